"""`replanner sim` (physics, operator, ground truth; cameras in a child process) and `replanner cameras`: the
simulated cell's inputs and outputs wired to Zenoh keys."""

from __future__ import annotations

import json
import logging
import signal
import subprocess
import sys
import threading
from collections.abc import Callable
from concurrent.futures import CancelledError, Future

import zenoh

from replanner.config import ReplannerConfig
from replanner.errors import InvalidInputError, ReplannerError
from replanner.model.robot import RobotModel
from replanner.sim.cloud_publisher import CloudPublisher
from replanner.sim.config import CellConfig
from replanner.sim.physics import PhysicsSim
from replanner.transport.keys import Keys, sim_keys
from replanner.transport.watch import ServiceWatch

log = logging.getLogger(__name__)


class SimNode:
    """The physics sim on Zenoh.

    In: the trajectory stream; `sim/gripper` and `sim/state` queries (JSON objects), answered from the physics
    loop's thread so a query callback never waits for pybullet. Out: joint states, `sim/truth` (also appended to
    the JSON-lines file `truth_log`) and `sim/bodies`.
    """

    def __init__(
        self,
        cfg: CellConfig,
        session: zenoh.Session,
        *,
        seed: int = 0,
        gui: bool = False,
        truth_log: str | None = None,
        operator: bool | None = None,
    ):
        self.session, self.truth_log = session, truth_log
        self.sim = PhysicsSim(
            cfg,
            seed=seed,
            gui=gui,
            operator=operator,
            publish_joint_state=self._put("joint_states"),
            publish_truth=self._truth,
            publish_bodies=self._put("bodies"),
        )
        self.keys = Keys(self.sim.robot.name, cfg.transport.namespace)
        self.skeys = sim_keys(self.keys.root)
        self._pubs: dict[str, zenoh.Publisher] = {}
        self._decl: list = []
        self._log = None
        self.cfg, self.watch = cfg, None

    def start(self) -> SimNode:
        s, sim = self.session, self.sim
        self._log = open(self.truth_log, "a") if self.truth_log else None  # noqa: SIM115 (closed in stop)
        self._pubs = {
            "joint_states": s.declare_publisher(self.keys.joint_states),
            "truth": s.declare_publisher(self.skeys["truth"]),
            "bodies": s.declare_publisher(self.skeys["bodies"]),
        }
        self._decl = [
            s.declare_subscriber(self.keys.trajectory, lambda sample: sim.on_trajectory(sample.payload.to_bytes())),
            s.declare_queryable(self.skeys["gripper"], self._queryable(sim.gripper)),
            s.declare_queryable(self.skeys["state"], self._queryable(lambda _request: sim.state())),
        ]
        sim.start()
        self.watch = ServiceWatch(s, self.keys, self.cfg.controller.robot_watchdog, self._lost)
        return self

    def _lost(self, reason: str) -> None:
        self.sim.stop_along(f"the service is lost: {reason}")

    def stop(self) -> None:
        if self.watch is not None:
            self.watch.close()
        for d in self._decl:
            d.undeclare()
        self.sim.stop()  # its last truth event goes out here; queries still waiting are answered with an error
        for p in self._pubs.values():
            p.undeclare()
        if self._log:
            self._log.close()

    def _put(self, name: str) -> Callable[[bytes | str], None]:
        return lambda data: self._pubs[name].put(data)

    def _truth(self, text: str) -> None:
        try:
            self._pubs["truth"].put(text)
        except Exception:
            log.exception("truth publishing failed")
        if self._log:
            self._log.write(text + "\n")
            self._log.flush()

    def _queryable(self, handler: Callable[[dict], dict]) -> Callable[[zenoh.Query], None]:
        def callback(query: zenoh.Query) -> None:
            try:
                payload = json.loads(query.payload.to_bytes()) if query.payload else {}
                if not isinstance(payload, dict):
                    raise InvalidInputError("the request must be a JSON object")
                fut = self.sim.submit(handler, payload)
            except (ReplannerError, ValueError) as err:
                query.reply_err(json.dumps({"error": str(err)}))
                query.drop()
                return
            fut.add_done_callback(lambda f: _reply(query, f))

        return callback


def _reply(query: zenoh.Query, fut: Future) -> None:
    try:
        query.reply(query.key_expr, json.dumps(fut.result()))
    except CancelledError:
        query.reply_err(json.dumps({"error": "the simulator stopped"}))
    except (InvalidInputError, ValueError) as err:
        query.reply_err(json.dumps({"error": str(err)}))
    except Exception as err:
        log.exception("sim request failed")
        query.reply_err(json.dumps({"error": f"internal error: {err}"}))
    finally:
        query.drop()


class CameraNode:
    """Simulated cameras on Zenoh: clouds on `<root>/clouds/<sensor>`, the arm drawn at the joint states or, with
    `mirror_sim`, the arm, the operator and the part as `sim/bodies` says. Arguments as CloudPublisher's."""

    def __init__(
        self,
        cfg: ReplannerConfig,
        session: zenoh.Session,
        static=(),
        *,
        rate_hz: float = 10.0,
        robot: RobotModel | None = None,
        mirror_sim: bool = False,
        seed: int = 0,
    ):
        self.session = session
        self.clouds = CloudPublisher(
            cfg, self._publish, static, rate_hz=rate_hz, robot=robot, mirror_sim=mirror_sim, seed=seed
        )
        self.keys = Keys(self.clouds.robot.name, cfg.transport.namespace)
        self._pubs: dict[str, zenoh.Publisher] = {}
        self._sub = None

    def start(self) -> CameraNode:
        s, clouds = self.session, self.clouds
        self._pubs = {name: s.declare_publisher(self.keys.cloud(name)) for name in clouds.sensors}
        if clouds.mirror_sim:  # the arm comes with the bodies, all of one instant
            key, on_input = sim_keys(self.keys.root)["bodies"], clouds.on_bodies
        else:
            key, on_input = self.keys.joint_states, clouds.on_joint_state
        self._sub = s.declare_subscriber(key, lambda sample: on_input(sample.payload.to_bytes()))
        clouds.start()
        return self

    def stop(self) -> None:
        if self._sub is not None:
            self._sub.undeclare()
        self.clouds.stop()
        for p in self._pubs.values():
            p.undeclare()

    def _publish(self, sensor: str, cloud: bytes) -> None:
        self._pubs[sensor].put(cloud)


def _wait_for_signal() -> threading.Event:
    done = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: done.set())
    return done


def run_sim(
    cfg: ReplannerConfig,
    conf: zenoh.Config,
    *,
    seed: int,
    gui: bool,
    truth_log: str | None,
    operator: bool,
    cameras_cmd: list[str] | None,
) -> None:
    from replanner.transport.refusals import Refusals, access_control_on
    from replanner.transport.session import open_session

    done = _wait_for_signal()
    refusals = Refusals.capture() if access_control_on(conf) else None  # the sim is the robot: it counts too
    session = open_session(conf)
    child = None
    try:
        node = SimNode(cfg, session, seed=seed, gui=gui, truth_log=truth_log, operator=operator).start()
        if cameras_cmd:  # rendering holds the GIL for tens of ms: in the same process it would stall the physics
            child = subprocess.Popen(cameras_cmd)
        print(
            f"replanner: sim of {node.sim.robot.name} on {node.keys.root} (seed {seed}, "
            f"operator {'on' if operator else 'off'}, cameras {'on' if cameras_cmd else 'off'}; Ctrl-C stops)",
            file=sys.stderr,
            flush=True,
        )
        while not done.wait(0.5):
            if child is not None and child.poll() is not None:
                print(f"replanner: the camera process exited ({child.returncode})", file=sys.stderr, flush=True)
                break
        node.stop()
        if refusals is not None:
            print(f"replanner: the sim refused {refusals.total} messages by access control", file=sys.stderr)
    finally:
        if child is not None and child.poll() is None:
            child.send_signal(signal.SIGINT)
            try:
                child.wait(5)
            except subprocess.TimeoutExpired:
                child.kill()
        session.close()


def run_cameras(cfg: ReplannerConfig, conf: zenoh.Config, *, seed: int) -> None:
    from replanner.transport.session import open_session
    from replanner.world.scene import scene_from_config

    done = _wait_for_signal()
    session = open_session(conf)
    try:
        sensors = cfg.perception.sensors if cfg.perception else []
        rate = cfg.sim.camera_rate_hz or min((s.rate_hz for s in sensors), default=10.0)
        node = CameraNode(cfg, session, scene_from_config(cfg), rate_hz=rate, mirror_sim=True, seed=seed).start()
        done.wait()
        node.stop()
    finally:
        session.close()
