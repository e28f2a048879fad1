"""numba's kernels are cached per version of the compiled sources: a helper changed in another module than the
kernel that inlines it compiles the kernel again (numba alone checks only the kernel's own file)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

from replanner.cache_dirs import KEEP, sources_digest

ROOT = Path(__file__).resolve().parents[1]


def _run(code: str, **env: str) -> dict:
    base = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "REPLANNER_CACHE_DIR")}
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=ROOT, env={**base, **env}
    )
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_the_digest_follows_the_modules_that_use_numba(tmp_path):
    (tmp_path / "sub").mkdir()
    kernel, helper, plain = tmp_path / "kernel.py", tmp_path / "sub" / "helper.py", tmp_path / "plain.py"
    kernel.write_text("import numba\n")
    helper.write_text("import numba\n\n@numba.njit\ndef f(x):\n    return x\n")
    plain.write_text("X = 1\n")
    first = sources_digest(tmp_path)
    plain.write_text("X = 2\n")
    assert sources_digest(tmp_path) == first  # a module without kernels compiles nothing
    helper.write_text("import numba\n\n@numba.njit\ndef f(x):\n    return x + 1\n")
    second = sources_digest(tmp_path)
    assert second != first
    (tmp_path / "new.py").write_text("from numba import njit\n")
    assert sources_digest(tmp_path) not in (first, second)


def test_kernels_compile_into_the_cache_of_their_source_version(tmp_path):
    code = """
import json, os
import numba
import replanner
from replanner.cache_dirs import sources_digest
from replanner.collision.boxes import box_centre
import numpy as np
box_centre(np.eye(4), np.zeros(3), np.zeros(3))
print(json.dumps([numba.config.CACHE_DIR, os.environ["NUMBA_CACHE_DIR"], sources_digest()]))
"""
    config_dir, env_dir, digest = _run(code, REPLANNER_CACHE_DIR=str(tmp_path))
    target = tmp_path / "numba" / digest
    assert Path(config_dir) == target and Path(env_dir) == target
    assert list(target.rglob("*.nbi"))  # the kernel's index, written there


def test_a_numba_cache_dir_set_by_the_user_is_kept(tmp_path):
    mine = tmp_path / "mine"
    code = "import json, numba, replanner; print(json.dumps([numba.config.CACHE_DIR]))"
    (config_dir,) = _run(code, REPLANNER_CACHE_DIR=str(tmp_path / "ours"), NUMBA_CACHE_DIR=str(mine))
    assert Path(config_dir) == mine
    assert not (tmp_path / "ours" / "numba").exists()


def test_only_the_most_recently_used_other_versions_are_kept(tmp_path):
    base = tmp_path / "numba"
    old = [base / f"v{i}" for i in range(KEEP + 2)]
    for i, d in enumerate(old):
        d.mkdir(parents=True)
        (d / "index.nbi").write_text("x")
        os.utime(d, (time.time() - 1000 + i, time.time() - 1000 + i))  # v0 the least recently used
    code = "import json, replanner, os; print(json.dumps([os.environ['NUMBA_CACHE_DIR']]))"
    (current,) = _run(code, REPLANNER_CACHE_DIR=str(tmp_path))
    assert Path(current).exists()
    kept = sorted(p.name for p in base.iterdir() if p != Path(current))
    assert kept == [d.name for d in old[-KEEP:]]
