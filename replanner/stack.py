"""One function builds the stack from a config; the service, the kinematic sim, the planning process and the benches
all use it.

    robot → world (static scene) → checker → planner → generator [→ perception] [→ monitor, plan worker, controller]
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Literal

from . import late_compiles
from .collision.exact import CollisionChecker
from .collision.paddings import with_map_margin
from .config import ReplannerConfig
from .control.controller import Controller
from .control.latency import LatencyAccount
from .model.geometry import Shape
from .model.robot import RobotModel
from .monitor import Monitor, build_monitor
from .perception import Perception
from .planning import InlineWorker, Planner, PlanWorker, ProcessWorker, ThreadWorker
from .planning.recording import JobRecorder
from .trajectory import Trajectory, TrajectoryGenerator
from .world.scene import World, scene_from_config


@dataclass
class Stack:
    """The parts of one robot's stack; those not asked for are None."""

    cfg: ReplannerConfig
    robot: RobotModel
    world: World
    checker: CollisionChecker
    planner: Planner
    generator: TrajectoryGenerator
    perception: Perception | None = None
    monitor: Monitor | None = None
    worker: PlanWorker | None = None
    controller: Controller | None = None

    def on_joint_state(self, js) -> None:
        """A measured joint state for everything that needs one (perception's self-filter, the controller)."""
        if self.perception is not None:
            self.perception.add_joint_state(js.stamp, js.position)
        if self.controller is not None:
            self.controller.on_joint_state(js)

    def close(self) -> None:
        """Stop the controller and its plan worker (a planning process exits)."""
        if self.controller is not None:
            self.controller.stop()
        elif self.worker is not None:
            self.worker.close()


def build_stack(
    cfg: ReplannerConfig,
    *,
    robot: RobotModel | None = None,
    static: Iterable[tuple[str, Shape, object]] | None = None,
    seed: int | None = None,
    cameras: bool = True,
    execute: Callable[[Trajectory, float], None] | None = None,
    plan_in: Literal["process", "thread", "inline"] | None = None,
    clock: Callable[[], float] = time.monotonic,
) -> Stack:
    """Build the parts `cfg` describes.

    Args:
        robot: a robot model already loaded from cfg.robot (saves loading the URDF again).
        static: (name, shape, T_base_object) objects for the world; default: the config's `scene:`.
        seed: the planner's seed (reproducible plans); also the planning process's.
        cameras: build perception for the configured sensors (False: static objects only).
        execute: execute(trajectory, start [clock s]) sends trajectories to the robot; given, the stack gets a
            monitor, a plan worker and a controller (not started).
        plan_in: "process" (a child process, the second core), "thread", or "inline" (planned when submitted,
            handed over by the worker's `deliver()`: simulation on a clock one drives); default: "process" if
            controller.planning_process, else "thread".
        clock: the controller's clock [s], shared with the robot and the sensors.
    """
    with late_compiles.building():  # the warm-ups compile here: that is when they should
        stack = _wire(cfg, robot, static, seed, cameras, execute, plan_in, clock)
    late_compiles.watch(start=stack.controller is not None)  # a compile from here on stalls a running arm
    return stack


def _wire(cfg, robot, static, seed, cameras, execute, plan_in, clock) -> Stack:
    plan_in = plan_in or ("process" if cfg.controller.planning_process else "thread")
    # the planning child builds its stack while this process builds its own: started first, waited for last
    child = ProcessWorker(cfg, seed, wait=False) if execute is not None and plan_in == "process" else None
    try:
        stack = _parts(cfg, robot, static, seed, cameras, execute, plan_in, clock, child)
        if child is not None:
            child.wait_ready()
        return stack
    except BaseException:
        if child is not None:
            child.close()
        raise


def _parts(cfg, robot, static, seed, cameras, execute, plan_in, clock, child) -> Stack:
    robot = robot or RobotModel.from_config(cfg.robot)
    world = World(robot)
    for name, shape, pose in scene_from_config(cfg) if static is None else static:
        world.add(name, shape, pose)
    checker = CollisionChecker.from_config(robot, world, cfg.collision)
    # plans (and the curves and swerves timed onto them) may keep a margin from the map the monitor does not ask for
    planning = with_map_margin(checker, cfg.planning.map_margin)
    planner = Planner.from_config(planning, cfg.planning, seed=seed)
    generator = TrajectoryGenerator.from_config(robot, planning, cfg.planning)
    stack = Stack(cfg, robot, world, checker, planner, generator)
    if cameras and cfg.perception is not None and cfg.perception.sensors:
        stack.perception = Perception.from_config(cfg, robot, world)
    if execute is None:
        return stack
    # the monitor thread must not wait CPython's default 5 ms for the interpreter behind perception or a planner
    sys.setswitchinterval(cfg.controller.gil_switch_interval)
    ssm = cfg.controller.speed_separation
    sensors = cfg.perception.sensors if stack.perception is not None else []
    frame_period = max((1.0 / s.rate_hz for s in sensors), default=0.0)
    latency = LatencyAccount(
        ssm.latency_window, ssm.latency_percentile, ssm.min_reaction_time, frame_period + cfg.controller.brake_latency
    )
    stack.monitor = build_monitor(
        checker,
        generator,
        cfg.controller,
        cfg.collision.allowed_contacts,
        reaction_time=latency.reaction_time if sensors else None,
        joint_state_age=latency.joint_state_age,
    )
    if plan_in == "process":
        stack.worker = child
    elif plan_in == "inline":
        stack.worker = InlineWorker(planner, generator, clock)
    else:
        stack.worker = ThreadWorker(planner, generator)
    if cfg.planning.record_jobs:
        stack.worker.recorder = JobRecorder(cfg.planning.record_jobs, cfg.core().model_dump(mode="json"))
    stack.controller = Controller(
        robot,
        checker,
        planner,
        generator,
        stack.monitor,
        stack.worker,
        execute,
        cfg.controller,
        sensors=[s.name for s in sensors],
        clock=clock,
        default_deadline=cfg.planning.deadline,
        latency=latency,
    )
    if stack.perception is not None:
        stack.perception.subscribe(stack.controller.on_map)
    return stack
