"""The `replanner` command."""

from __future__ import annotations

import json
import logging
import sys
from importlib import resources
from pathlib import Path

import typer
from rich.console import Console
from rich.table import Table

from replanner.config import ReplannerConfig, load_config
from replanner.errors import ReplannerError

app = typer.Typer(
    help="replanner: reactive replanning for robot arms next to people.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)
bench_app = typer.Typer(help="Benchmarks: fixed seeds, printed figures (median, p95, n).", no_args_is_help=True)
app.add_typer(bench_app, name="bench")

err_console = Console(stderr=True, soft_wrap=True)  # never break a path or a field name

CONFIG_HELP = "Robot config: a YAML file, or the name of a shipped profile (panda, iiwa)."


def shipped_profiles() -> list[str]:
    return sorted(
        p.name.removesuffix(".yaml") for p in resources.files("replanner_configs").iterdir() if p.name.endswith(".yaml")
    )


def resolve_config(config: str) -> ReplannerConfig:
    """Load a config file, or a shipped profile by name."""
    path = Path(config)
    if not path.exists() and config in shipped_profiles():
        with resources.as_file(resources.files("replanner_configs") / f"{config}.yaml") as p:
            return load_config(p)
    return load_config(path)


def _fail(err: Exception) -> None:
    err_console.print(f"[bold red]error:[/] {err}", highlight=False, markup=True)
    raise typer.Exit(2)


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
    Console().print(t)


@bench_app.command("collision")
def bench_collision(
    config: str = typer.Option("panda", "--config", "-c", help=CONFIG_HELP),
    seed: int = typer.Option(0, min=0, help="Seed of the scene and the configurations."),
    runs: int = typer.Option(5, min=1, help="Measured runs (plus one warm-up)."),
    n: int = typer.Option(5000, min=10, help="Configurations per run."),
    voxels: int = typer.Option(50_000, min=0, help="Occupied voxels in the octree."),
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of a table."),
) -> None:
    """Boolean and distance checks/s of the robot against a table and an octree of ~50,000 1 cm voxels."""
    from replanner.bench import collision

    try:
        cfg = resolve_config(config)
        result = collision.run(cfg, seed=seed, runs=runs, n=n, voxels=voxels)
    except ReplannerError as err:
        _fail(err)
    if as_json:
        print(json.dumps(result, indent=2))
    else:
        _print_collision(result)


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


@bench_app.command("perception")
def bench_perception(
    config: str = typer.Option("panda", "--config", "-c", help=CONFIG_HELP),
    seed: int = typer.Option(0, min=0, help="Seed of the scene."),
    frames: int = typer.Option(40, min=30, help="Timed frames (at least 30)."),
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of a table."),
) -> None:
    """Whole perception pipeline on 640x480 clouds rendered by pybullet; octomap-python as the reference."""
    from replanner.bench import perception

    try:
        cfg = resolve_config(config)
        result = perception.run(cfg, seed=seed, frames=frames)
    except (ReplannerError, ValueError) as err:
        _fail(err)
    if as_json:
        print(json.dumps(result, indent=2))
    else:
        _print_perception(result)


@app.command("demo")
def demo() -> None:
    """Simulated pick-and-place with an intruding operator (not built yet)."""
    _fail(RuntimeError("`replanner demo` is not built yet: it arrives with issue 7 (sim, service and client)."))


def main() -> None:
    logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    app(prog_name="replanner")


if __name__ == "__main__":
    sys.exit(main())
