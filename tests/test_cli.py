"""The `replanner` command, run as a user would."""

from __future__ import annotations

import json
import os
import subprocess
import sys

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
    assert out.returncode == 2 and "--policy must be one of replan, stop-and-wait, none" in out.stderr
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
