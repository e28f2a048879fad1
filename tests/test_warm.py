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
from replanner.world import kernels as wk

build_stack(load_config("panda"), static=[table()], cameras=True)
called = {
    wk: ["chain_frames", "body_poses", "body_boxes", "boxes_hit_table", "octree_stream", "count_cells"],
    tk: ["quintic_peaks", "path_bounds", "slowest_entry"],
    pk: ["voxelize", "mark_inside", "neighbour_counts", "union_sorted", "in_sorted", "cell_keys", "shadow_cells"],
}
print(json.dumps([f"{m.__name__}.{n}" for m, names in called.items() for n in names if not getattr(m, n).signatures]))
"""


def test_building_the_stack_compiles_every_kernel_the_hot_path_calls():
    out = subprocess.run([sys.executable, "-c", CODE], capture_output=True, text=True, timeout=600)  # a fresh process
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout.strip().splitlines()[-1]) == []
