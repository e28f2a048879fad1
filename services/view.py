"""`replanner view`: the cell, live, in a browser (viser). It is a Zenoh client like any other and is read-only
unless a control on the page is used. It draws the robot at the measured joints and a ghost at the commanded
ones, the map, the objects, the path, the state and the latency; with the sim it also draws the operator.

A slow browser never slows the service: the view draws at a fixed rate from the newest data it holds, and
stale updates are replaced rather than queued.
"""

from __future__ import annotations

import contextlib
import logging
import sys
import threading
import time

import numpy as np
import zenoh

from replanner.apps.cell_watch import CellWatch
from replanner.apps.client import Client
from replanner.errors import ReplannerError
from replanner.model.robot import RobotModel
from replanner.perception.camera import pose_from_config
from replanner.sim.config import CellConfig
from replanner.transport.keys import Keys

log = logging.getLogger(__name__)

LAYERS = ("robot", "ghost", "map", "objects", "path", "operator", "cameras")


def _wxyz(R: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return np.array([w, x, y, z])


def headless_chromium(url: str | None = None, size=(960, 640)):
    """Debian's chromium, headless, through its chromedriver (software WebGL); nothing is downloaded."""
    import shutil

    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    chromium, driver = shutil.which("chromium"), shutil.which("chromedriver")
    if not (chromium and driver):
        raise ReplannerError("chromium and chromedriver are missing: `make test` installs them (apt-get)")
    opts = webdriver.ChromeOptions()
    opts.binary_location = chromium
    for a in (
        "--headless=new",
        "--no-sandbox",
        "--disable-dev-shm-usage",
        f"--window-size={size[0]},{size[1]}",
        "--use-gl=swiftshader",
        "--enable-unsafe-swiftshader",
    ):
        opts.add_argument(a)
    browser = webdriver.Chrome(service=Service(driver), options=opts)
    if url is not None:
        browser.get(url)
    return browser


def _same(a, b) -> bool:
    return b is not None and np.array_equal(a, b)


def _shape_mesh(shape: dict, color):
    """A trimesh of a protocol shape (box, cylinder, sphere, mesh); a malformed one raises KeyError / ValueError."""
    import trimesh

    kind = shape["type"]
    if kind == "box":
        mesh = trimesh.creation.box(extents=shape["size"])
    elif kind == "cylinder":
        mesh = trimesh.creation.cylinder(radius=shape["radius"], height=shape["length"])
    elif kind == "sphere":
        mesh = trimesh.creation.icosphere(radius=shape["radius"])
    elif kind == "mesh":
        mesh = trimesh.Trimesh(np.asarray(shape["vertices"], float), np.asarray(shape["faces"], int))
    else:
        raise ValueError(f"unknown shape type {kind!r}")
    mesh.visual.face_colors = color
    return mesh


def _mesh_or_name(name: str, urdf_dir):
    """The URDF's mesh file as the collision model finds it (package://, relative, absolute); else the name."""
    from replanner.model.urdf import resolve_mesh

    try:
        return resolve_mesh(name, urdf_dir)
    except ReplannerError:
        return name


def height_colours(points: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """uint8 RGB per point from blue (low) to red (high) over [lo, hi] (the workspace's z range)."""
    if len(points) == 0:
        return np.zeros((0, 3), np.uint8)
    s = np.clip((points[:, 2] - lo) / max(hi - lo, 1e-6), 0.0, 1.0)[:, None]
    low, mid, high = np.array([40, 90, 220.0]), np.array([60, 200, 90.0]), np.array([230, 60, 40.0])
    c = np.where(s < 0.5, low + (mid - low) * (s / 0.5), mid + (high - mid) * ((s - 0.5) / 0.5))
    return c.astype(np.uint8)


class CellView:
    """The page: a viser server drawing a CellWatch at `rate_hz`, with controls that use a Client.

    Args:
        cfg: the cell's config (the robot, the cameras, the sim's operator).
        session: an open Zenoh session.
        host, port: where the page is served.
        rate_hz: drawing rate [Hz].
        map_hz: how often the map is asked for [Hz].
    """

    def __init__(
        self,
        cfg: CellConfig,
        session: zenoh.Session,
        host: str = "127.0.0.1",
        port: int = 8080,
        rate_hz: float = 20.0,
        map_hz: float = 2.0,
        robot_name: str | None = None,
    ):
        import viser
        import yourdfpy
        from viser.extras import ViserUrdf

        self.cfg, self.rate_hz = cfg, rate_hz
        self.robot = RobotModel.from_config(cfg.robot)
        self.keys = Keys(robot_name or self.robot.name, cfg.transport.namespace)
        self.watch = CellWatch(session, self.keys, self.robot.joint_names, map_hz=map_hz)
        self.client = Client(session, self.keys.robot, self.keys.namespace, timeout=5.0)
        with contextlib.redirect_stdout(sys.stderr):  # viser prints a banner; stdout is for --json and our lines
            self.server = viser.ViserServer(host=host, port=port, label="replanner", verbose=False)
        self.url = f"http://{host}:{self.server.get_port()}"
        self.server.scene.set_up_direction("+z")
        self.server.initial_camera.position = (1.35, -1.15, 0.95)
        self.server.initial_camera.look_at = (0.35, 0.0, 0.35)
        # one root frame per layer, made before what hangs under it: hiding a layer hides the root
        self._roots = {name: self.server.scene.add_frame(f"/{name}", show_axes=False) for name in LAYERS}
        urdf_dir = self.robot.urdf_path.parent
        urdf = yourdfpy.URDF.load(
            str(self.robot.urdf_path),
            build_collision_scene_graph=False,
            filename_handler=lambda fname: str(_mesh_or_name(fname, urdf_dir)),
        )
        self.arm = ViserUrdf(self.server, urdf, root_node_name="/robot")
        self._ghost_root = self.server.scene.add_frame("/ghost/arm", show_axes=False)
        self.ghost = ViserUrdf(self.server, urdf, root_node_name="/ghost/arm", mesh_color_override=(0.2, 0.5, 1.0, 0.3))
        self._moving = self.robot.joint_names  # the URDF's actuated joints also include the fingers
        self._urdf_joints = list(self.arm.get_actuated_joint_names())
        self.updates = 0  # drawing steps done
        self.rate = 0.0  # drawing steps per second, measured
        self.last_message = ""
        self._drawn = {"map": -1, "scene": -1, "trajectory": -1}
        self._drawn_q = self._drawn_qc = None
        self._forearm = None  # the operator's capsule, made when the sim first says where it is
        self._objects: list = []
        self._attached: list = []  # (handle, link, T_link_object)
        self._build_gui()
        self._draw_cameras()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------------ page
    def _build_gui(self) -> None:
        gui = self.server.gui
        self.label = gui.add_markdown("**state** connecting…")
        self.latency = gui.add_markdown("")
        self.history = gui.add_markdown("")
        with gui.add_folder("Goal"):
            home = ", ".join(f"{v:.3f}" for v in self.robot.home)
            self.joints_text = gui.add_text("Joints [rad]", home)
            self.send_joints = gui.add_button("Send joint goal")
            self.send_pose = gui.add_button("Send pose goal (gizmo)")
            self.cancel = gui.add_button("Cancel goal")
        with gui.add_folder("Layers"):
            self.layer_boxes = {name: gui.add_checkbox(name, True) for name in LAYERS}
            self.pause_map = gui.add_checkbox("pause map", False)
        self.message = gui.add_markdown("")
        tip = self.robot.link_pose(self.robot.home, self.robot.tip_link)
        self.gizmo = self.server.scene.add_transform_controls(
            "/goal_gizmo", scale=0.15, position=tip[:3, 3], wxyz=_wxyz(tip[:3, :3])
        )
        self.send_joints.on_click(lambda _e: self._send_joints())
        self.send_pose.on_click(lambda _e: self._send_pose())
        self.cancel.on_click(lambda _e: self._cancel())
        for name, box in self.layer_boxes.items():
            box.on_update(lambda _e, name=name: self.set_layer(name, self.layer_boxes[name].value))
        self.pause_map.on_update(lambda _e: setattr(self.watch, "map_paused", self.pause_map.value))

    def _say(self, text: str) -> None:
        self.last_message = text
        self.message.content = text
        print(f"replanner view: {text}", file=sys.stderr, flush=True)

    def _send_joints(self) -> None:
        try:
            q = [float(x) for x in self.joints_text.value.replace(",", " ").split()]
            fut = self.client.send_goal(q)
            self._say(f"goal {fut.id} sent (joints)")
        except (ReplannerError, ValueError) as err:
            self._say(f"goal not sent: {err}")

    def _send_pose(self) -> None:
        from scipy.spatial.transform import Rotation

        w, x, y, z = np.asarray(self.gizmo.wxyz, float)
        pose = {
            "link": self.robot.tip_link,
            "position": [float(v) for v in self.gizmo.position],
            "quat_xyzw": Rotation.from_quat([x, y, z, w]).as_quat().tolist(),
        }
        try:
            fut = self.client.send_goal(None, pose)
            self._say(f"goal {fut.id} sent (pose of {self.robot.tip_link})")
        except ReplannerError as err:
            self._say(f"goal not sent: {err}")

    def _cancel(self) -> None:
        goal = (self.watch.status or {}).get("goal_id")
        if not goal:
            return self._say("no active goal to cancel")
        try:
            self.client.cancel(goal)
            self._say(f"goal {goal} cancelled")
        except ReplannerError as err:
            self._say(f"cancel failed: {err}")

    def set_layer(self, name: str, visible: bool) -> None:
        """Show or hide one of LAYERS."""
        self.layer_boxes[name].value = visible
        self._roots[name].visible = visible

    def _draw_cameras(self) -> None:
        for s in self.cfg.perception.sensors if self.cfg.perception else ():
            T = pose_from_config(s.pose)
            self.server.scene.add_camera_frustum(
                f"/cameras/{s.name}",
                fov=np.radians(s.fov_y_deg),
                aspect=s.width / s.height,
                scale=0.15,
                position=T[:3, 3],
                wxyz=_wxyz(T[:3, :3]),
                color=(90, 90, 90),
            )

    # ------------------------------------------------------------------ drawing
    def _urdf_cfg(self, q: np.ndarray) -> np.ndarray:
        full = np.zeros(len(self._urdf_joints))
        for i, name in enumerate(self._moving):
            if name in self._urdf_joints:
                full[self._urdf_joints.index(name)] = q[i]
        return full

    def step(self) -> None:
        """One drawing step from the newest data (never waits for the service)."""
        w, scene = self.watch, self.server.scene
        # a pose already drawn is not sent again: a standing arm costs neither this process nor the page anything
        if w.q is not None and not _same(w.q, self._drawn_q):
            self._drawn_q = w.q
            self.arm.update_cfg(self._urdf_cfg(w.q))
        qc = w.commanded()
        self._ghost_root.visible = qc is not None and self.layer_boxes["ghost"].value  # nothing commanded yet: no ghost
        if qc is not None and not _same(qc, self._drawn_qc):
            self._drawn_qc = qc
            self.ghost.update_cfg(self._urdf_cfg(qc))
        if w.trajectory_count != self._drawn["trajectory"]:
            self._drawn["trajectory"] = w.trajectory_count
            path = w.path()
            if path is not None and len(path) >= 2:
                tips = self.robot.link_pose(path[:: max(1, len(path) // 200)], self.robot.tip_link)[:, :3, 3]
                seg = np.stack([tips[:-1], tips[1:]], axis=1)
                scene.add_line_segments("/path/tip", seg, colors=(250, 140, 0), thickness=0.006)
        if w.map_count != self._drawn["map"]:
            self._drawn["map"] = w.map_count
            vox = w.voxels
            ws = self.cfg.perception.workspace if self.cfg.perception else None
            lo, hi = (ws.min[2], ws.max[2]) if ws is not None else (0.0, 1.5)
            scene.add_point_cloud(
                "/map/voxels",
                vox if len(vox) else np.zeros((1, 3), np.float32),
                height_colours(vox, lo, hi) if len(vox) else np.zeros((1, 3), np.uint8),
                point_size=float(w.resolution or 0.01),
                point_shape="square",
                visible=bool(len(vox)),
            )
        if w.scene_count != self._drawn["scene"]:
            self._drawn["scene"] = w.scene_count
            self._draw_objects(w.objects, w.attachments)
        if w.q is not None and self._attached:
            poses = self.robot.fk(w.q)
            for handle, link, T_in in self._attached:
                T = poses[self.robot.link_index(link)] @ T_in
                handle.position, handle.wxyz = T[:3, 3], _wxyz(T[:3, :3])
        if w.bodies is not None and isinstance(w.bodies.get("operator"), list):
            self._draw_operator(w.bodies["operator"])
        self._draw_text()
        self.updates += 1

    def _draw_objects(self, objects: list[dict], attachments: list[dict]) -> None:
        """Static objects where they stand; attached ones on their links (moved with the arm in `step`)."""
        from scipy.spatial.transform import Rotation

        for h in self._objects:
            h.remove()
        self._objects, self._attached = [], []
        for obj in [*objects, *attachments]:
            try:
                attached = "link" in obj
                pose = obj["pose_in_link"] if attached else obj["pose"]
                pos = np.asarray(pose["position"], float)
                quat = np.asarray(pose.get("quat_xyzw") or (0, 0, 0, 1), float)
                color = (90, 160, 90, 255) if attached else (170, 150, 120, 255)
                name = f"/objects/{'attached/' if attached else ''}{obj['name']}"
                handle = self.server.scene.add_mesh_trimesh(
                    name, _shape_mesh(obj["shape"], color), position=pos, wxyz=(quat[3], *quat[:3])
                )
                self._objects.append(handle)
                if attached:
                    self.robot.link_index(obj["link"])  # an unknown link is a bad reply, not a drawing crash
                    T_in = np.eye(4)
                    T_in[:3, :3], T_in[:3, 3] = Rotation.from_quat(quat).as_matrix(), pos
                    self._attached.append((handle, obj["link"], T_in))
            except (KeyError, TypeError, ValueError, ReplannerError) as err:
                self.watch.ignore("scene object", err)

    def _draw_operator(self, pose: list) -> None:
        import trimesh

        op = getattr(getattr(self.cfg, "sim", None), "operator", None)
        if op is None or len(pose) != 7 or not np.all(np.isfinite(pose)):
            return
        if self._forearm is None:
            mesh = trimesh.creation.capsule(height=op.arm_length, radius=op.arm_radius)
            mesh.visual.face_colors = (230, 180, 150, 255)
            self._forearm = self.server.scene.add_mesh_trimesh("/operator/forearm", mesh)
        x, y, z, w_ = pose[3:]
        self._forearm.position, self._forearm.wxyz = tuple(pose[:3]), (w_, x, y, z)

    def _draw_text(self) -> None:
        w = self.watch
        st = w.status or {}
        if w.problem:
            self.label.content = f"**{w.problem}**"
            return
        goal = st.get("goal_id") or "none"
        progress = st.get("progress")
        prog = "" if progress is None else f" · progress {100 * progress:.0f} %"
        contacts = ""
        if w.bodies is not None:
            gap = "—" if w.clearance is None else f"{100 * w.clearance:.1f} cm"
            contacts = f" · sim: clearance to the operator {gap}, contacts {len(w.contacts)}"
        self.label.content = (
            f"**state** {st.get('state', '?')} · goal {goal}{prog} · map {len(w.voxels):,} voxels{contacts}"
            f" · view {self.rate:.0f} Hz"
        )
        lat = st.get("latency") or {}
        rows = [
            f"| {k} | {1e3 * v['median']:.0f} | {1e3 * v['p99']:.0f} |"
            for k, v in lat.items()
            if isinstance(v, dict)
            and isinstance(v.get("median"), (int, float))
            and isinstance(v.get("p99"), (int, float))
        ]
        self.latency.content = ("| latency [ms] | median | p99 |\n|---|---|---|\n" + "\n".join(rows)) if rows else ""
        trs = list(w.transitions)[-5:]
        self.history.content = "\n".join(
            f"- {t.get('from', '?')} → {t.get('to', '?')}: {str(t.get('reason', ''))[:80]}" for t in trs
        )

    # ------------------------------------------------------------------ running
    def start(self) -> CellView:
        self._thread = threading.Thread(target=self._run, name="view", daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:
        period = 1.0 / self.rate_hz
        told: object = ...  # say the first state, whatever it is
        window: list[float] = []
        while not self._stop.is_set():
            t0 = time.monotonic()
            try:
                self.step()
            except Exception:  # a drawing bug must not end the view: log it, draw again next time
                log.exception("drawing failed")
            window = [t for t in window if t > t0 - 2.0] + [t0]
            self.rate = (len(window) - 1) / max(window[-1] - window[0], 1e-6) if len(window) > 1 else 0.0
            if self.watch.problem != told:
                told = self.watch.problem
                print(f"replanner view: {told or 'connected to ' + self.keys.root}", file=sys.stderr, flush=True)
            self._stop.wait(max(0.0, period - (time.monotonic() - t0)))

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        self.watch.close()
        self.client.close()
        with contextlib.redirect_stdout(sys.stderr):
            self.server.stop()
