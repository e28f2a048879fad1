"""The `replanner` command, run as a user would."""

from __future__ import annotations

import ast
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from tests.conftest import CONFIGS


def replanner(*args, timeout=300):
    env = {**os.environ, "COLUMNS": "200"}  # no line wrapping inside messages
    return subprocess.run(
        [sys.executable, "-m", "replanner_services.cli", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=env,
    )


def test_bench_collision_json():
    out = replanner("bench", "collision", "--json", "--runs", "2", "--n", "200", "--voxels", "5000")
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout)
    assert result["bench"] == "collision" and result["robot"] == "panda"
    assert result["scene"]["octree_voxels"] == 5000
    for key in ("boolean_single", "boolean_batched"):
        assert result[key]["checks_per_s_median"] > 0 and result[key]["runs"] == 2
    lat = result["boolean_single"]["latency_us"]
    assert 0 < lat["median"] <= lat["p95"] and lat["n"] == 400
    assert result["distance"]["latency_us"]["n"] == 300
    assert 0.0 < result["valid_fraction"] < 1.0
    layer = result["planning_layer"]
    assert layer["verdicts_unlike_fcl"] == 0 and layer["checks_per_s_median"] > 0
    assert abs(layer["free_for_certain"] + layer["contact_for_certain"] + layer["unsure_after_spheres"] - 1.0) < 1e-9
    assert 0.0 <= layer["unsure_to_fcl"] <= layer["unsure_after_spheres"]  # the convex pass decides the most of them
    m = result["machine"]  # how fast the machine was around the run: figures of two hours compare at like times
    assert m["cores"] == os.cpu_count() and m["processor"] and m["reference_ms_before"] > 0 < m["reference_ms_after"]


def test_bench_reflex_json():
    out = replanner("bench", "reflex", "--json", "--n", "2")
    assert out.returncode == 0, out.stderr
    r = json.loads(out.stdout)
    assert [(row["voxel_mm"], row["vertices"]) for row in r["rows"]] == [(10, 4701), (5, 4701), (10, 2468), (5, 2468)]
    for row in r["rows"]:
        assert row["voxels"] > 1000 and row["pairs_within_r_max"] > 0 and row["force_computation_ms"]["n"] == 2
    assert r["seed_001_kernels"]["update_ms"]["n"] == 200
    w, wo = r["seed_001_wall"]
    assert w["joint4_final_distance_m"] > wo["joint4_final_distance_m"]


def test_bench_collision_table_for_iiwa_profile_by_name():
    out = replanner("bench", "collision", "-c", "iiwa", "--runs", "1", "--n", "100", "--voxels", "1000")
    assert out.returncode == 0, out.stderr
    assert "iiwa" in out.stdout and "is_valid" in out.stdout


def test_bad_flag_says_what_to_change():
    out = replanner("bench", "collision", "--runs", "0")
    assert out.returncode == 2
    assert "--runs" in out.stderr and "greater than or equal to 1" in out.stderr


def test_bad_config_names_file_and_field(tmp_path):
    data = yaml.safe_load((CONFIGS / "panda.yaml").read_text())
    data["collision"]["paddin"] = 0.01
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(data))
    out = replanner("bench", "collision", "--config", str(path))
    assert out.returncode == 2
    assert str(path) in out.stderr and "collision.paddin" in out.stderr and "padding" in out.stderr


def test_demo_bad_flags_say_what_to_change():
    out = replanner("demo", "--policy", "yolo")
    allowed = "replan+reflex, replan, reflex, stop-and-wait, none"
    assert out.returncode == 2 and f"--policy must be one of {allowed}" in out.stderr
    out = replanner("demo", "--config", "panda", "--cycles", "1")  # the panda profile has no bins
    assert out.returncode == 2 and "sim.task.bins names 'bin_a', which is not in scene:" in out.stderr


def test_bench_perception_json():
    out = replanner("bench", "perception", "--json", "--frames", "30")
    assert out.returncode == 0, out.stderr
    r = json.loads(out.stdout)
    assert r["bench"] == "perception" and r["frames"] == 30
    assert r["sensor"]["width"] == 640 and r["sensor"]["height"] == 480
    assert r["ms_per_frame"]["n"] == 30 and r["ms_per_frame"]["median"] > 0
    counts = r["count_out_per_stage_median"]
    assert counts["input"] == 640 * 480 and counts["input"] >= counts["range"] >= counts["crop"] >= counts["voxels"]
    assert r["reference_octomap_insert_ms"]["n"] >= 1
    c = r["clearing"]
    assert c["box_voxels_mapped"] > 0 and c["frames_to_clear_measured"] <= c["frames_to_clear_bound"] <= 5


def test_bench_reaction_json_cameras_render_in_their_own_process():
    out = replanner("bench", "reaction", "--json", "--runs", "2")
    assert out.returncode == 0, out.stderr
    r = json.loads(out.stdout)
    assert r["bench"] == "reaction" and r["runs"] == 2 and r["speed_separation"].startswith("off")
    assert r["drop_to_map_ms"]["n"] == 2  # the child process's cameras saw both boxes
    hi = r["time_to_contact_s"][1]
    for row in r["rows"]:  # each box would have met the arm's first link within the stated time (pybullet)
        assert row["time_to_contact_s"] <= hi
        assert row["status"] in ("succeeded", "failed") and (row["braked"] or row["pending_to_spliced_ms"] is not None)
        if row["pending_to_spliced_ms"] is not None:  # the plan is a part of the replan's time
            assert 0 < row["replan_plan_ms"] < row["pending_to_spliced_ms"]


# --------------------------------------------------------------------------------------------- layout
SERVICES = Path(__file__).resolve().parents[1] / "services"


def _cli_imports() -> dict[str, list[tuple[str, str | None]]]:
    """For each services/cli*.py: (cli module it imports, the name taken from it; None for the module itself)."""
    mods = {p.stem: ast.parse(p.read_text(), str(p)) for p in sorted(SERVICES.glob("cli*.py"))}

    def local(module: str | None, level: int) -> str | None:  # ".cli_common" or "replanner_services.cli_common"
        if level:
            return module
        prefix = "replanner_services"
        return None if module is None else "" if module == prefix else module.removeprefix(f"{prefix}.")

    edges: dict[str, list[tuple[str, str | None]]] = {m: [] for m in mods}
    for mod, tree in mods.items():
        bound: dict[str, str] = {}  # local name -> the cli module bound to it (`from . import cli_bench`)
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                target = local(node.module, node.level)
                if target in mods:
                    edges[mod] += [(target, a.name) for a in node.names]
                elif target in (None, ""):  # from . import cli_bench / from replanner_services import cli_bench
                    for a in node.names:
                        if a.name in mods:
                            edges[mod].append((a.name, None))
                            bound[a.asname or a.name] = a.name
            elif isinstance(node, ast.Import):
                edges[mod] += [(t, None) for a in node.names if (t := local(a.name, 0)) in mods]
        for node in ast.walk(tree):  # cli_bench._print_collision: an underscore name reached through the module
            if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in bound:
                edges[mod].append((bound[node.value.id], node.attr))
    return edges


def test_cli_modules_import_each_other_as_a_tree_of_public_names():
    edges = _cli_imports()
    assert {"cli", "cli_common"} <= set(edges), sorted(edges)
    private = [(m, t, n) for m, es in edges.items() for t, n in es if n is not None and n.startswith("_")]
    assert not private, f"underscore names imported across cli modules (module, from, name): {private}"
    graph = {m: sorted({t for t, _ in es if t != m}) for m, es in edges.items()}
    state: dict[str, str] = {}

    def visit(m: str, path: list[str]) -> None:
        state[m] = "open"
        for t in graph[m]:
            assert state.get(t) != "open", f"import cycle: {' -> '.join([*path, m, t])}"
            if t not in state:
                visit(t, [*path, m])
        state[m] = "done"

    for m in graph:
        if m not in state:
            visit(m, [])
    assert graph["cli_common"] == [], "cli_common is the leaf: it imports no other cli module"


HELPS = """
import contextlib, io, json, sys
from replanner_services.cli import app

out = {}
for command in sys.argv[1:]:
    stdout, stderr, code = io.StringIO(), io.StringIO(), 0
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        try:
            app([command, "--help"], prog_name="replanner")
        except SystemExit as end:  # --help exits
            code = end.code or 0
    out[command] = [code, stdout.getvalue(), stderr.getvalue()]
print(json.dumps(out))
"""
HELP_COMMANDS = ("serve", "goal", "robot", "cancel", "status", "scene", "sim", "pick-and-place", "router")


@pytest.fixture(scope="module")
def helps() -> dict[str, subprocess.CompletedProcess]:
    """`replanner <command> --help` of every command below, as the command prints it (COLUMNS=200), read in one
    process: each `replanner` process spends seconds importing on a busy machine, the same for every command."""
    env = {**os.environ, "COLUMNS": "200"}
    out = subprocess.run(
        [sys.executable, "-c", HELPS, *HELP_COMMANDS], capture_output=True, text=True, timeout=300, env=env
    )
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout.strip().splitlines()[-1])
    return {c: subprocess.CompletedProcess([c, "--help"], code, o, e) for c, (code, o, e) in got.items()}


def test_connection_flags_are_the_same_on_every_session_command(helps):
    """Like zenoh-python's examples: -m/--mode, -e/--connect, -l/--listen, --zenoh-config, defined once."""
    for command in ("serve", "goal", "robot", "cancel", "status", "scene", "sim", "pick-and-place"):
        out = helps[command]
        assert out.returncode == 0, (command, out.stderr)
        for flags in (r"--mode\s+-m\b", r"--connect\s+-e\b", r"--listen\s+-l\b", r"--zenoh-config\b"):
            assert re.search(flags, out.stdout), (command, flags, out.stdout)
    out = helps["router"]
    assert re.search(r"--listen\s+-l\b", out.stdout) and "[default: router]" in out.stdout, out.stdout


def test_help_keeps_units_and_config_profiles(helps):
    out = helps["goal"]
    assert "Joint goal [rad]" in out.stdout and "Planning deadline [s]" in out.stdout, out.stdout
    assert "(panda, iiwa, demo)" in out.stdout


def test_zenoh_flags_reach_a_child_process_without_the_listen_port():
    from replanner_services.cli_common import ZenohFlags

    flags = ZenohFlags.of("client", ["tcp/10.0.0.2:7447", "tcp/10.0.0.3:7447"], ["tcp/0.0.0.0:7448"], "client")
    assert flags.args(listen=False) == [
        *("-m", "client"),
        *("-e", "tcp/10.0.0.2:7447", "-e", "tcp/10.0.0.3:7447"),
        *("--zenoh-config", "client"),
    ]
    assert flags.args()[-4:-2] == ["-l", "tcp/0.0.0.0:7448"]
    assert ZenohFlags.of(None, None, None, None).args() == []


def test_a_config_error_is_one_red_line_and_exit_2():
    out = replanner("status", "-c", "no-such-profile", timeout=60)
    assert out.returncode == 2 and out.stdout == ""
    assert out.stderr.startswith("error: config file not found: no-such-profile") and "panda" in out.stderr
    assert "Traceback" not in out.stderr


def test_busy_processes_and_services_die_with_a_killed_parent(tmp_path):
    """A demo or bench killed outright (SIGKILL, no cleanup) leaves no busy loop or service running."""
    parent = (
        "import sys, time\n"
        "from pathlib import Path\n"
        "from replanner_services.procs import Load, Proc\n"
        "load = Load(1).__enter__()\n"
        f"p = Proc('sleeper', [sys.executable, '-c', 'import time; time.sleep(600)'], Path({str(tmp_path)!r}))\n"
        "print(load.procs[0].pid, p.p.pid, flush=True)\n"
        "time.sleep(600)\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", parent], stdout=subprocess.PIPE, text=True)
    pids = [int(x) for x in proc.stdout.readline().split()]
    assert len(pids) == 2 and all(Path(f"/proc/{p}").exists() for p in pids)
    proc.kill()
    proc.wait()
    for pid in pids:  # the children are not ours to reap: gone means gone or a zombie of init's
        for _ in range(100):
            st = Path(f"/proc/{pid}/stat")
            if not st.exists() or st.read_text().split(") ")[1].startswith("Z"):
                break
            time.sleep(0.1)
        else:
            raise AssertionError(f"process {pid} outlived its killed parent")
