"""`replanner bench ...`: fixed seeds, printed figures (median, p95, n); `--json` for the raw result."""

from __future__ import annotations

import functools
import inspect
from collections.abc import Callable

import typer
from rich.console import Console
from rich.table import Table

from replanner.errors import ReplannerError
from replanner.sections import CollisionLayer

from .cli_common import ConfigOpt, JsonOpt, LoadOpt, fail, print_json, resolve_config

app = typer.Typer(help="Benchmarks: fixed seeds, printed figures (median, p95, n).", no_args_is_help=True)


def bench(name: str, table: Callable[[dict], None]):
    """`replanner bench <name>` of a function that checks its options and returns what to measure, a `run() ->
    dict`; adds --load and --json. The result says how busy the machine was (see --load) and how fast: a fixed
    workload's time before and after the run, as runs hours apart compare only at like times."""

    def register(command: Callable[..., Callable[[], dict]]):
        @functools.wraps(command)
        def main(*, load: int, as_json: bool, **options) -> None:
            from replanner.bench.machine import describe, reference_ms

            from .procs import Load

            try:
                run = command(**options)
                before = reference_ms()
                with Load(load) as busy:
                    result = run()
            except ReplannerError as err:
                fail(err)
            result["load"] = busy.describe()
            result["machine"] = describe(before, reference_ms())
            if as_json:
                print_json(result)
            else:
                table(result)

        # typer reads the options from the signature: the command's own, then the two every bench has
        own = inspect.signature(command, eval_str=True)
        shared = [
            inspect.Parameter("load", inspect.Parameter.KEYWORD_ONLY, default=0, annotation=LoadOpt),
            inspect.Parameter("as_json", inspect.Parameter.KEYWORD_ONLY, default=False, annotation=JsonOpt),
        ]
        main.__signature__ = own.replace(parameters=[*own.parameters.values(), *shared], return_annotation=None)
        app.command(name)(main)
        return command

    return register


def _print_collision(result: dict) -> None:
    t = Table(
        title=f"collision checks: {result['robot']}, table + {result['scene']['octree_voxels']} voxels "
        f"({result['valid_fraction']:.0%} of configurations valid)"
    )
    for col in ("query", "rate (median)", "latency median", "latency p95", "n"):
        t.add_column(col)
    s, b, d = result["boolean_single"], result["boolean_batched"], result["distance"]
    t.add_row(
        "is_valid, 1 per call",
        f"{s['checks_per_s_median']:,.0f} /s",
        f"{s['latency_us']['median']:.1f} µs",
        f"{s['latency_us']['p95']:.1f} µs",
        f"{s['runs']} × {s['n_per_run']}",
    )
    t.add_row(
        f"is_valid_batch, {b['chunk']} per call",
        f"{b['checks_per_s_median']:,.0f} /s",
        "-",
        "-",
        f"{b['runs']} × {b['n_per_run']}",
    )
    t.add_row(
        "clearance (distance)",
        f"{d['queries_per_s_median']:,.0f} /s",
        f"{d['latency_us']['median']:.0f} µs",
        f"{d['latency_us']['p95']:.0f} µs",
        str(d["latency_us"]["n"]),
    )
    g = result["planning_layer"]
    runs = f"{b['runs']} × {b['n_per_run']}"
    t.add_row("planning layer (spheres), whole runs", f"{g['checks_per_s_median']:,.0f} /s", "-", "-", runs)
    par = f"{g['parallel_checks_per_s_median']:,.0f} /s"
    t.add_row(f"planning layer, whole runs on {g['cores']} cores", par, "-", "-", runs)
    t.add_row(f"planning layer, {g['chunk']} per call", f"{g['chunked_checks_per_s_median']:,.0f} /s", "-", "-", runs)
    t.add_row(
        f"planning layer + convex pass ({g['unsure_after_spheres']:.0%} unsure) + FCL ({g['unsure_to_fcl']:.1%})",
        f"{g['with_fcl_checks_per_s_median']:,.0f} /s",
        "-",
        "-",
        f"{runs}; {g['verdicts_unlike_fcl']} verdicts unlike FCL's",
    )
    Console().print(t)


@bench("collision", _print_collision)
def bench_collision(
    config: ConfigOpt = "panda",
    seed: int = typer.Option(0, min=0, help="Seed of the scene and the configurations."),
    runs: int = typer.Option(5, min=1, help="Measured runs (plus one warm-up)."),
    n: int = typer.Option(5000, min=10, help="Configurations per run."),
    voxels: int = typer.Option(50_000, min=0, help="Occupied voxels in the octree."),
) -> Callable[[], dict]:
    """Boolean and distance checks/s of the robot against a table and an octree of ~50,000 1 cm voxels."""
    from replanner.bench import collision

    return lambda: collision.run(resolve_config(config), seed=seed, runs=runs, n=n, voxels=voxels)


def _print_perception(r: dict) -> None:
    t = Table(
        title=f"perception: {r['sensor']['width']}x{r['sensor']['height']} organised cloud at "
        f"{r['resolution_m']} m, {r['frames']} frames (+{r['warmup_frames']} warm-up)"
    )
    for col in ("stage", "points/voxels out (median)", "ms median", "ms p95"):
        t.add_column(col)
    counts = r["count_out_per_stage_median"]
    t.add_row("input", str(counts.get("input", "")), "", "")
    for stage, s in r["ms_per_stage"].items():
        key = {"transform_crop": "crop", "voxel_grid": "voxels", "range": "range"}.get(stage, stage)
        t.add_row(stage, str(counts.get(key, "")), f"{s['median']:.2f}", f"{s['p95']:.2f}")
    f = r["ms_per_frame"]
    t.add_row(
        "[bold]whole frame", f"{r['occupied_voxels_median']} occupied", f"[bold]{f['median']:.1f}", f"{f['p95']:.1f}"
    )
    Console().print(t)
    ref, c = r["reference_octomap_insert_ms"], r["clearing"]
    Console().print(
        f"octomap-python ray-cast insertion of the same cloud: {ref['median']:.0f} ms median (n={ref['n']})"
    )
    Console().print(
        f"clearing: a removed box ({c['box_voxels_mapped']} voxels) was gone after "
        f"{c['frames_to_clear_measured']} frames (bound {c['frames_to_clear_bound']})"
    )


@bench("perception", _print_perception)
def bench_perception(
    config: ConfigOpt = "panda",
    seed: int = typer.Option(0, min=0, help="Seed of the scene."),
    frames: int = typer.Option(40, min=30, help="Timed frames (at least 30)."),
) -> Callable[[], dict]:
    """Whole perception pipeline on 640x480 clouds rendered by pybullet; octomap-python as the reference."""
    from replanner.bench import perception

    return lambda: perception.run(resolve_config(config), seed=seed, frames=frames)


def _print_planning(r: dict) -> None:
    t = Table(title=f"planning: {r['robot']}, {r['planner']}, deadline {r['deadline_s']} s, seed {r['seed']}")
    for col in (
        "family",
        "n",
        "success",
        "plan ms med / p95",
        "search / simplify ms med",
        "timing ms med / p95",
        "duration s med",
        "naive s med",
        "naive/timed",
        "worst v / a / j",
        "tube max",
        "collisions",
    ):
        t.add_column(col)
    for name, d in [*r["families"].items(), ("overall", r["overall"])]:
        w = d.get("worst", {})
        t.add_row(
            name,
            str(d["problems"]),
            f"{d['success_rate']:.0%}",
            f"{d['plan_ms']['median']:.0f} / {d['plan_ms']['p95']:.0f}",
            f"{d['search_ms']['median']:.1f} / {d['simplify_ms']['median']:.1f}",
            f"{d['timing_ms']['median']:.1f} / {d['timing_ms']['p95']:.1f}",
            f"{d['duration_s']['median']:.2f}",
            f"{d['naive_duration_s']['median']:.2f}",
            f"{d.get('naive_over_timed_total', 0):.3f}",
            " / ".join(f"{w[k]:.3f}" for k in ("velocity_ratio", "acceleration_ratio", "jerk_ratio")) if w else "-",
            f"{w['tube_deviation']:.3f}" if w else "-",
            f"{d['colliding_samples']} of {d['samples']}" if "samples" in d else "-",
        )
    Console().print(t)
    over = r["deadline_overrun_ms_max"]
    Console().print(f"slowest plan(), simplification included: {over:+.1f} ms against its deadline (+: over it)")
    late = r["late_plans"]
    if late:
        Console().print(
            f"{len(late)} plans returned after their deadline's {r['deadline_margin_ms']:.0f} ms margin: "
            + ", ".join(f"{x['family']} #{x['index']} {x['over_ms']:+.1f} ms" for x in late[:5])
        )


@bench("planning", _print_planning)
def bench_planning(
    config: ConfigOpt = "panda",
    seed: int = typer.Option(0, min=0, help="Seed of the scenes, starts and goals (and OMPL)."),
    per_family: int = typer.Option(25, min=1, help="Problems per scene family."),
    deadline: float | None = typer.Option(None, min=0.01, help="Planning deadline [s]; default from the config."),
    verify: bool = typer.Option(True, help="Check every trajectory at 1 kHz: limits, tube, pybullet collisions."),
    families: str = typer.Option(
        "all",
        help="Comma-separated families, 'ours' (table, shelf, bin, cage) or 'standard' (bookshelf_small, "
        "bookshelf_tall, bookshelf_thin, box, table_pick, table_under_pick: grasps, planned with 2 mm padding).",
    ),
    layer: CollisionLayer | None = typer.Option(
        None, help="Collision layer of the search (default: the config's planning.collision_layer)."
    ),
    person: bool = typer.Option(
        False, help="A person-sized column of voxels beside each problem, a fresh map each plan (a planning job's)."
    ),
) -> Callable[[], dict]:
    """Plan, simplify and time problems of seeded scene families: ours and the standard benchmark families."""
    from replanner.bench import planning

    chosen = planning.pick_families(families)
    cfg = resolve_config(config)
    if layer is not None:
        cfg = cfg.model_copy(update={"planning": cfg.planning.model_copy(update={"collision_layer": layer})})
    return lambda: planning.run(
        cfg, seed=seed, per_family=per_family, deadline=deadline, verify_all=verify, families=chosen, person=person
    )


def _print_replay(result: dict) -> None:
    t = Table(
        "jobs",
        "plans",
        "solved",
        "plan ms median",
        "p95",
        "recorded median",
        "recorded p95",
        title=f"replay of {result['directory']}: {result['collision_layer']} layer",
    )
    for name, part in [("all", result["overall"]), *result["purposes"].items()]:
        figures = [part[k][q] for k in ("plan_ms", "recorded_plan_ms") for q in ("median", "p95")]
        t.add_row(name, str(part["plans"]), f"{part['success_rate']:.0%}", *(f"{v:.1f}" if v else "-" for v in figures))
    Console().print(t)


@bench("replay", _print_replay)
def bench_replay(
    directory: str = typer.Argument(..., help="A directory a service recorded its jobs in (planning.record_jobs)."),
    config: str | None = typer.Option(None, "--config", "-c", help="This config (default: the one recorded there)."),
    repeat: int = typer.Option(1, min=1, help="Plans of each job (each with its map built anew)."),
    purpose: str | None = typer.Option(None, help="Only jobs of these purposes, comma-separated: goal, replan, hold."),
    layer: CollisionLayer | None = typer.Option(None, help="Collision layer of the search (default: the config's)."),
) -> Callable[[], dict]:
    """Plan again the jobs a service recorded (`demo --record-jobs DIR`): plan ms here next to the service's."""
    from replanner.bench import replay

    cfg = replay.config_of(directory, config, layer)
    return lambda: replay.run(cfg, directory, repeat=repeat, purposes=purpose and purpose.split(","))


def _print_reflex(result: dict) -> None:
    pts, cores = result["frame_points"], result["cores"]
    t = Table(
        title=f"the GPU potential-field paper's virtual forces: {result['robot']}, {pts:,} points in the frame, "
        f"{cores} cores"
    )
    for col in (
        "voxel",
        "vertices",
        "voxels",
        "pairs < r_max",
        "map ms (median / p95)",
        "forces ms (median / p95)",
        "paper GPU / CPU ms",
    ):
        t.add_column(col)
    for r in result["rows"]:
        m, f = r["map_creation_ms"], r["force_computation_ms"]
        t.add_row(
            f"{r['voxel_mm']:g} mm",
            str(r["vertices"]),
            f"{r['voxels']:,}",
            f"{r['pairs_within_r_max']:,}",
            f"{m['median']:.1f} / {m['p95']:.1f}",
            f"{f['median']:.1f} / {f['p95']:.1f}",
            f"{r['paper_gpu_ms']:g} / {r['paper_cpu_ms']:g}",
        )
    Console().print(t)
    sw = result["swerve"]
    Console().print(
        "the reflex in the loop, ms per swerve direction (median / p95): "
        + ", ".join(f"{m} {sw[m]['ms']['median']:.1f} / {sw[m]['ms']['p95']:.1f}" for m in ("forces", "kernels"))
        + f" ({sw['voxels']:,} voxels, {sw['vertices']} vertices; control period {sw['control_period_ms']:.1f} ms)"
    )
    k, (w, wo) = result["seed_001_kernels"], result["seed_001_wall"]
    u = k["update_ms"]
    Console().print(
        f"Baumgartner and Klančar's kernels: {u['median']:.2f} / {u['p95']:.2f} ms per update "
        f"(median / p95, n={u['n']}) for "
        f"{k['points_of_interest']} points of interest; reaching past a wall, joint 4 ends "
        f"{w['joint4_final_distance_m'] * 100:.1f} cm from it with avoidance, {wo['joint4_final_distance_m'] * 100:.1f}"
        f" cm without (goal within {w['goal_error_m'] * 1e3:.1f} / {wo['goal_error_m'] * 1e3:.1f} mm)"
    )


@bench("reflex", _print_reflex)
def bench_reflex(
    config: ConfigOpt = "panda",
    seed: int = typer.Option(0, min=0, help="Seed of the person's place, the arm's configuration, the vertices."),
    n: int = typer.Option(30, min=1, help="Timed repetitions per row."),
) -> Callable[[], dict]:
    """The GPU potential-field paper's virtual forces (its Table II setting): map creation and forces per row."""
    from replanner.bench import reflex

    return lambda: reflex.run(resolve_config(config), seed=seed, n=n)


def _print_monitor(result: dict) -> None:
    t = Table(title=f"monitor: {result['robot']}, {result['octree_voxels']} voxels")
    for col in ("figure", "value", "bar"):
        t.add_column(col)
    c, w = result["remaining_path_check_ms"], result["remaining_path_waypoints"]
    t.add_row(
        f"remaining-path check ({w['median']:.0f} waypoints), median / p95",
        f"{c['median']:.2f} / {c['p95']:.2f} ms (n={c['n']})",
        "median <= 5 ms",
    )
    f, g, n = result["full_check_ms"], result["full_check_in_loop_ms"], result["full_check_new_map_ms"]
    t.add_row(
        "full check: map + objects + attached, median / p95", f"{f['median']:.2f} / {f['p95']:.2f} ms", "p95 <= 2 ms"
    )
    t.add_row("  the same beside the running controller", f"{g['median']:.2f} / {g['p95']:.2f} ms", "-")
    t.add_row("  the same on a map not yet checked (builds its tree)", f"{n['median']:.2f} / {n['p95']:.2f} ms", "-")
    t.add_row("check rate idle", f"{result['check_rate_idle_hz']:.0f} Hz (cap {result['check_rate_cap_hz']:.0f})", "-")
    t.add_row(
        "check rate while planning",
        f"{result['check_rate_while_planning_hz']:.0f} Hz ({result['plans_during_window']} plans)",
        ">= 100 Hz",
    )
    Console().print(t)


@bench("monitor", _print_monitor)
def bench_monitor(
    config: ConfigOpt = "panda",
    seed: int = typer.Option(0, min=0, help="Seed of the clutter and the planning load."),
    voxels: int = typer.Option(50_000, min=1000, help="Occupied voxels in the octree."),
) -> Callable[[], dict]:
    """Remaining-path check time against ~50k voxels, and the monitor's check rate idle vs while planning."""
    from replanner.bench import monitor

    return lambda: monitor.run(resolve_config(config), seed=seed, voxels=voxels)


def _print_reaction(result: dict) -> None:
    title = f"reaction: {result['runs']} boxes dropped {result['time_to_contact_s']} s ahead of the arm"
    rows = [
        ("drop_to_map_ms", "drop -> in the map"),
        ("map_to_pending_ms", "map -> PENDING"),
        ("pending_to_spliced_ms", "PENDING -> spliced (decided)"),
        ("pending_to_landed_ms", "PENDING -> new trajectory takes over"),
        ("replan_plan_ms", "the plan itself (within PENDING -> spliced)"),
    ]
    Console().print(_stats_table(title, "interval", rows, result, "{:.0f}"))
    Console().print(
        f"replanned without stopping: {result['replanned_without_stopping']} of {result['runs']}; braked: "
        f"{result['braked']}; goals reached: {result['succeeded']}; min clearance to the box "
        f"(pybullet): {result['min_clearance_m'] * 1000:.1f} mm; speed and separation: {result['speed_separation']}"
    )


@bench("reaction", _print_reaction)
def bench_reaction(
    config: ConfigOpt = "panda",
    seed: int = typer.Option(0, min=0, help="Seed of the drops (place, size, time)."),
    runs: int = typer.Option(20, min=1, help="Boxes dropped (one per run)."),
    ssm: bool = typer.Option(
        False,
        "--ssm/--no-ssm",
        help="Keep speed and separation on: it stops the arm for anything this close (a box could be a person), "
        "so the replanning chain is measured with it off unless asked.",
    ),
) -> Callable[[], dict]:
    """A box dropped into the arm's path: time to the map, to PENDING, to the spliced trajectory."""
    from replanner.bench import reaction

    return lambda: reaction.run(resolve_config(config), seed=seed, runs=runs, speed_separation=ssm)


def _print_view(result: dict) -> None:
    t = Table(title=f"web view: {result['robot']}, {result['map_voxels']:,} voxels, browser {result['browser']}")
    for col in ("figure", "value", "bar"):
        t.add_column(col)
    t.add_row("monitor checks/s without the view", f"{result['monitor_rate_without_hz']:.1f}", "-")
    t.add_row("monitor checks/s with the view", f"{result['monitor_rate_with_hz']:.1f}", "-")
    t.add_row("ratio", f"{result['ratio']:.3f}", f"≥ {result['bars']['ratio']}")
    t.add_row(
        "view updates/s (median)",
        f"{result['view_updates_per_s_median']:.1f}",
        f"≥ {result['bars']['view_updates_per_s']}",
    )
    Console().print(t)


@bench("view", _print_view)
def bench_view(
    config: ConfigOpt = "panda",
    voxels: int = typer.Option(50_000, min=100, help="Voxels the camera fills the map with (at most its points)."),
    seconds: float = typer.Option(20.0, min=5.0, help="Length of each phase [s]."),
    rounds: int = typer.Option(2, min=1, help="Rounds of (without, with) the view."),
    browser: bool = typer.Option(False, "--browser", help="Also a headless chromium on the page (same machine)."),
    seed: int = typer.Option(0, min=0, help="Seeds the map's points."),
) -> Callable[[], dict]:
    """The web view's cost to the service (monitor checks/s with and without it) and its drawing rate."""
    from . import view_bench

    return lambda: view_bench.run(config, voxels=voxels, seconds=seconds, rounds=rounds, seed=seed, browser=browser)


def _print_service(result: dict) -> None:
    t = Table(title=f"service end to end: {result['robot']}, {result['transport']}")
    for col in ("interval", "median", "p95", "n"):
        t.add_column(col)
    for key, label, unit in [
        ("state_query_ms", "state query round trip", "ms"),
        ("goal_accept_ms", "goal request -> accepted", "ms"),
        ("goal_result_s", "goal request -> result", "s"),
        ("trajectory_s", "of which the arm moves", "s"),
        ("overhead_ms", "the rest (plan, time, transport, settle)", "ms"),
    ]:
        v = result[key]
        t.add_row(label, f"{v['median']:.3f} {unit}", f"{v['p95']:.3f} {unit}", str(v["n"]))
    Console().print(t)


@bench("service", _print_service)
def bench_service(
    config: ConfigOpt = "panda",
    seed: int = typer.Option(0, min=0, help="Seed of the goals."),
    goals: int = typer.Option(20, min=1, help="Goals sent (one after the other)."),
) -> Callable[[], dict]:
    """End to end over Zenoh: serve and robot --kinematic as processes; request -> result of simple goals."""
    from replanner.bench import service

    return lambda: service.run(config, resolve_config(config), seed=seed, goals=goals)


def _print_splice(result: dict) -> None:
    title = f"splice: {result['robot']}, {result['splice_ms']['n']} seeded mid-motion states"
    rows = [("splice_ms", "every splice"), ("spliced_ms", "spliced"), ("refused_ms", "refused")]
    Console().print(_stats_table(title, "", rows, result))
    Console().print(f"refused: {result['refused']} (bar: p95 <= {result['bars']['splice_ms_p95']} ms)")


@bench("splice", _print_splice)
def bench_splice(
    config: ConfigOpt = "panda",
    seed: int = typer.Option(0, min=0, help="Seed of the motions, the splice times and the new goals."),
    n: int = typer.Option(100, min=1, help="Splices (refusals included: they are on the same hot path)."),
) -> Callable[[], dict]:
    """A new path spliced onto a motion at full speed, from seeded mid-motion states: ms per splice."""
    from replanner.bench import splice

    return lambda: splice.run(resolve_config(config), seed=seed, n=n)


def _print_scene_edit(result: dict) -> None:
    Console().print(
        f"scene-edit: {result['runs']} boxes added onto the path: went into one in {result['passed_through']} runs; "
        f"replanned around it in {result['replanned']}, failed with a reason in {result['failed_with_reason']}"
    )


@bench("scene-edit", _print_scene_edit)
def bench_scene_edit(
    config: ConfigOpt = "panda",
    seed: int = typer.Option(0, min=0, help="Seed of the edits (when, where, how big)."),
    runs: int = typer.Option(20, min=1, help="Boxes added, one per run."),
) -> Callable[[], dict]:
    """A box added to the scene onto the path of a moving arm: does the arm ever go into it? (pybullet says)"""
    from replanner.bench import scene_edit

    return lambda: scene_edit.run(resolve_config(config), seed=seed, runs=runs)


def _print_block(r: dict) -> None:
    u = r["unblocked"]
    t = Table(
        title=f"block: forearm held {r['hold_s']:.0f} s or box left on the path; unblocked {u['duration_s']:.2f} s"
    )
    for col in ("policy", "forearm <= +3 s", "box <= +3 s", "reached (forearm / box)", "extra s, median", "stops"):
        t.add_column(col)
    for policy in r["policies"]:
        p = r[policy]

        def pct(v):
            return "-" if v is None else f"{v:.0%}"

        t.add_row(
            policy,
            pct(p["forearm_reached_within_3s"]),
            pct(p["box_reached_within_3s"]),
            f"{pct(p['forearm_reached'])} / {pct(p['box_reached'])}",
            "-" if p["extra_s"]["median"] is None else f"{p['extra_s']['median']:.1f}",
            str(p["protective_stops"]),
        )
    Console().print(t)
    for policy in r["policies"]:
        p = r[policy]
        Console().print(
            f"{policy}: collisions {p['collisions']}, separation below the S_p in force at {p['separation_below_sp']} "
            f"instants (least S - S_p {p['least_separation_minus_sp_m']} m)"
        )


@bench("block", _print_block)
def bench_block(
    config: ConfigOpt = "demo",
    seed: int = typer.Option(0, min=0, help="Seed of the forearms' and boxes' poses."),
    poses: int = typer.Option(20, min=0, help="Forearms set across the transfer path, held still, then taken away."),
    boxes: int = typer.Option(5, min=0, help="Boxes set down on the path and left there."),
    hold: float = typer.Option(10.0, min=0.0, help="Seconds a forearm is held still."),
    policy: list[str] = typer.Option(["replan", "stop-and-wait"], help="Policies to run (replan, stop-and-wait)."),
) -> Callable[[], dict]:
    """The KineoWorks reactive-planning paper's experiment: the arm sent across a blocked transfer path, on a simulated
    clock; per policy, reached or not, time against the unblocked transfer, stops, separation against S_p."""
    from replanner.bench import block
    from replanner.sim.config import load_cell_config

    for p in policy:
        if p not in block.POLICIES:
            fail(typer.BadParameter(f"--policy must be one of {', '.join(block.POLICIES)}, got {p!r}"))
    if poses + boxes == 0:
        fail(typer.BadParameter("--poses and --boxes are both 0: nothing to measure"))
    cfg = load_cell_config(config)
    return lambda: block.run(cfg, seed=seed, poses=poses, boxes=boxes, hold=hold, policies=tuple(policy))


def _stats_table(title: str, head: str, rows: list[tuple[str, str]], result: dict, fmt: str = "{:.2f}") -> Table:
    """A table of (key, label) rows of `result`'s {median, p95, n} figures [ms]."""
    t = Table(title=title)
    for col in (head, "median ms", "p95 ms", "n"):
        t.add_column(col)
    for key, label in rows:
        v = result[key]
        cell = [("-" if v[k] is None else fmt.format(v[k])) for k in ("median", "p95")]
        t.add_row(label, *cell, str(v["n"]))
    return t
