"""`replanner view` in a real browser: Debian's chromium, headless, driven by selenium through chromedriver (both
installed by the Makefile with apt-get; nothing is downloaded at run time). It runs against a live serve + kinematic
robot, with a camera feeding the map."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
import yaml
from replanner_services.procs import Proc, replanner_cmd
from replanner_services.view import CellView, headless_chromium

from replanner.perception.camera import pose_from_config
from replanner.sim.config import load_cell_config
from replanner.transport import messages as m
from replanner.transport.session import free_port, node_session
from tests.conftest import CONFIGS
from tests.test_service import HOME, _wait

START = [0.6, -0.4, 0.0, -2.3, 0.0, 1.9, 0.785]  # not home: the page's joint goal (home) must move the arm
BOX = (np.array([0.55, 0.35, 0.25]), 0.2)  # a cube the camera sees [m, base frame], beside the arm


def _browser():
    return headless_chromium()


def _text(browser) -> str:
    # the page's rendered text in one native call: selenium's `.text` runs a script that reads the style of every
    # element, which took a starved software renderer 10 to 30 s a call beside two busy processes
    return browser.execute_script("return document.body.innerText")


def _pixels(png: bytes) -> np.ndarray:
    import io

    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), np.int16)


def _changed(a: np.ndarray, b: np.ndarray) -> int:
    """Pixels of the 3D canvas (left of the control panel) that differ between two screenshots."""
    w = int(a.shape[1] * 0.72)
    return int((np.abs(a[:, :w] - b[:, :w]).max(axis=2) > 30).sum())


class BoxCamera:
    """The configured camera, publishing the cube's points (its faces on a 1 cm grid) in its optical frame."""

    def __init__(self, session, cfg, key):
        T = pose_from_config(cfg.perception.sensors[0].pose)
        c, s = BOX
        g = np.arange(-s / 2, s / 2 + 1e-9, 0.01)
        a, b = np.meshgrid(g, g)
        pts = []
        for axis in range(3):
            for side in (-s / 2, s / 2):
                p = np.zeros(a.shape + (3,))
                p[..., axis] = side
                p[..., (axis + 1) % 3], p[..., (axis + 2) % 3] = a, b
                pts.append(p.reshape(-1, 3))
        base = np.concatenate(pts) + c
        self.points = ((base - T[:3, 3]) @ T[:3, :3]).astype(np.float32)  # into the camera's frame
        self.pub = session.declare_publisher(key)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self):
        while not self.stop.wait(0.1):
            self.pub.put(m.encode_cloud(time.time(), self.points, "front"))

    def close(self):
        self.stop.set()
        self.thread.join(2.0)


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("view")
    data = yaml.safe_load((CONFIGS / "panda.yaml").read_text())
    front = data["perception"]["sensors"][0]
    front.update(width=64, height=48)
    data["perception"]["sensors"] = [front]
    data["controller"] = {"speed_separation": {"enabled": False}}
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    data["transport"] = {**data.get("transport", {}), "endpoint": endpoint}
    cfg_path = tmp / "panda_view.yaml"
    cfg_path.write_text(yaml.safe_dump(data))
    cfg = load_cell_config(str(cfg_path))
    joints = ",".join(str(v) for v in START)
    procs = [
        Proc("serve", replanner_cmd("serve", "-c", str(cfg_path), "-l", endpoint, "-v"), tmp),
        Proc(
            "robot", replanner_cmd("robot", "--kinematic", "-c", str(cfg_path), "-e", endpoint, "--joints", joints), tmp
        ),
    ]
    session = node_session(endpoint)
    camera = BoxCamera(session, cfg, f"replanner/@v1/panda/clouds/{front['name']}")
    view = browser = None
    try:
        view = CellView(cfg, session, port=free_port()).start()
        _wait(
            lambda: view.watch.problem is None and view.watch.q is not None,
            60,
            "the view connected\n" + "\n".join(p.tail() for p in procs),
        )
        _wait(lambda: len(view.watch.voxels) > 100, 30, "the cube in the map")
        browser = _browser()
        browser.get(view.url)
        yield view, browser, procs
    finally:
        if browser is not None:
            browser.quit()
        if view is not None:
            view.stop()
        camera.close()
        session.close()
        for p in procs:
            p.stop()


def _until(pred, timeout, what):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return
        time.sleep(0.5)
    raise AssertionError(f"timed out waiting for {what}")


def test_the_page_draws_robot_and_map_and_sends_a_goal(cell, tmp_path):
    view, browser, procs = cell
    _until(lambda: "WAITING" in _text(browser), 180, "the state label on the page")

    # the meshes load in the browser: wait until hiding the robot changes the picture, then the map
    shown = {}

    def layer_shows(name) -> bool:
        shown[name] = browser.get_screenshot_as_png()
        with_it = _pixels(shown[name])
        view.set_layer(name, False)
        time.sleep(0.5)
        without = _pixels(browser.get_screenshot_as_png())
        view.set_layer(name, True)
        time.sleep(0.5)
        return _changed(with_it, without) > {"robot": 3000, "map": 300}[name]

    _until(lambda: layer_shows("robot"), 300, "the robot drawn on the page")
    _until(lambda: layer_shows("map"), 300, "the map drawn on the page")
    (tmp_path / "view.png").write_bytes(shown["map"])  # robot and map drawn (another screenshot waits for a frame)
    # a goal from the page: its joint field holds home; the button sends it and the service moves the arm there.
    # One script finds the button and runs the page's own click handler: every WebDriver command waits on a starved
    # software renderer (reading each button's text took minutes), and a native click waits on a rendered frame,
    # which took over selenium's 120 s to give (CI with two busy processes)
    clicked = browser.execute_script(
        "const b = [...document.querySelectorAll('button')].find((b) => b.innerText.trim() === arguments[0]);"
        "if (b) b.click();"
        "return b !== undefined;",
        "Send joint goal",
    )
    assert clicked, "no 'Send joint goal' button on the page"
    _until(lambda: "sent" in view.last_message, 120, "the page's goal sent")
    _until(lambda: np.abs(view.watch.q - np.array(HOME)).max() < 1e-3, 120, f"the arm at home ({view.last_message})")
    _until(lambda: "WAITING" in _text(browser), 120, "the service done")
    assert view.rate >= 10.0, f"the view draws at {view.rate:.1f} Hz"
    assert all(p.alive() for p in procs)


def test_no_service_is_said_on_the_page_and_a_restart_is_picked_up(tmp_path):
    cfg = load_cell_config("panda")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session = node_session(endpoint)  # connects to nothing yet
    view = CellView(cfg, session, port=free_port()).start()
    browser = serve = None
    try:  # the view's server thread must stop whatever fails: it would keep pytest from exiting
        browser = _browser()
        browser.get(view.url)
        _until(
            lambda: "no service on replanner/@v1/panda" in _text(browser),
            60,
            "the page saying there is no service",
        )
        # garbage on the streams it reads is counted and ignored; it keeps drawing
        root = "replanner/@v1/panda"
        for key, junk in [("status", b"\xff{"), ("trajectory", b"junk"), ("sim/bodies", b"[1, 2]"),
                          ("joint_states", b"\x00\x01"), ("transitions", b"42")]:  # fmt: skip
            session.put(f"{root}/{key}", junk)
        drawn = view.updates
        _until(lambda: view.watch.bad >= 5 and view.updates > drawn + 5, 30, "the view ignoring garbage")
        # a service's start (imports, its stack, its planning process) took over 60 s beside two busy processes
        serve = Proc("serve", replanner_cmd("serve", "-c", "panda", "--no-cameras", "-l", endpoint), tmp_path)
        _until(lambda: "WAITING" in _text(browser), 300, "the page picking it up")
        serve.stop()
        _until(lambda: "no service" in _text(browser), 120, "the page noticing")
        serve = Proc("serve", replanner_cmd("serve", "-c", "panda", "--no-cameras", "-l", endpoint), tmp_path)
        _until(lambda: "WAITING" in _text(browser), 300, "the restart picked up")
    finally:
        if browser is not None:
            browser.quit()
        view.stop()
        session.close()
        if serve is not None:
            serve.stop()
