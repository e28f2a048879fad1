"""The compiled kernels the hot path calls are compiled (or loaded) when the stack is built, not in the middle of a
motion: a first compile holds the GIL for seconds and stalls perception and the monitor with it."""

from __future__ import annotations

import json
import subprocess
import sys

CODE = """
import json
from replanner.bench.scenes import table
from replanner.config import load_config
from replanner.perception import kernels as pk
from replanner.stack import build_stack
from replanner.trajectory import kernels as tk
from replanner.collision import boxes as cb
from replanner.collision import broadphase as wb
from replanner.model import kinematics as mk
from replanner.world import kernels as wk

build_stack(load_config("panda"), static=[table()], cameras=True)
called = {
    mk: ["chain_frames"],
    cb: ["body_poses", "body_boxes"],
    wk: ["boxes_hit_table", "octree_stream", "count_cells"],
    wb: ["broadphase"],
    tk: ["quintic_peaks", "path_bounds", "slowest_entry"],
    pk: ["voxelize", "mark_inside", "neighbour_counts", "union_sorted", "in_sorted", "cell_keys", "shadow_cells"],
}
print(json.dumps([f"{m.__name__}.{n}" for m, names in called.items() for n in names if not getattr(m, n).signatures]))
"""


def test_building_the_stack_compiles_every_kernel_the_hot_path_calls():
    out = subprocess.run([sys.executable, "-c", CODE], capture_output=True, text=True, timeout=600)  # a fresh process
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout.strip().splitlines()[-1]) == []


RUN = """
import json
from replanner import late_compiles
from replanner.bench import reaction, scene_edit
from replanner.config import load_config

if __name__ == "__main__":
    cfg = load_config("panda")
    out = reaction.run(cfg, runs=2, seed=3)  # boxes dropped on the path: map, monitor, replan, splice
    edit = scene_edit.run(cfg, runs=1, seed=3)  # an object added: the static scene's layers
    swerved = reaction.run(cfg.override({"controller": {"reaction": "replan_reflex"}}), runs=1, seed=3)  # the reflex
    statuses = [r["status"] for x in (out, edit, swerved) for r in x["rows"]]
    print(json.dumps({"new": late_compiles.new_signatures(), "statuses": statuses}))
"""


def test_a_running_stack_meets_no_argument_types_its_warm_ups_missed(tmp_path):
    # Fails on the old code: shadow_cells got a strided camera origin, count_cells read-only keys and the sphere
    # layer a read-only Q, each compiled mid-motion on a cold cache (perception silent for 1 s, the arm in the box).
    # Replans, a scene edit and a swerve: each path a running stack takes to its kernels.
    script = tmp_path / "run.py"  # a file, not -c: the sim's renderer is a spawned process that imports __main__
    script.write_text(RUN)
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stderr[-3000:]
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert result["new"] == [], (result["new"], result["statuses"])
    missed = [line for line in out.stderr.splitlines() if "warm_up" in line]  # the planning child's, or a compile
    assert missed == [], missed
