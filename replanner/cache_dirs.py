"""Where replanner keeps what it computes once per machine: the self-clearance tables and numba's compiled kernels.

numba checks a cached kernel against its own source file only. A kernel that inlines or calls a helper of another
module keeps the helper's old machine code when only that module changes (a `git pull` that touches `kernels.py`
alone, say): a fixed collision test would not run. The kernels' cache is therefore a directory named by a digest
of every module that uses numba; a change to any of them compiles them all again, once, on the next run.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent
KEEP = 3  # kernel caches of other source versions kept (the most recently used): a checkout switched back and forth


def default_cache_dir() -> Path:
    """$REPLANNER_CACHE_DIR, else $XDG_CACHE_HOME/replanner, else ~/.cache/replanner."""
    root = os.environ.get("REPLANNER_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "replanner"
    )
    return Path(root)


def sources_digest(root: Path = PACKAGE) -> str:
    """A digest of the modules under `root` that use numba (their paths and contents)."""
    h = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        text = path.read_bytes()
        if b"numba" in text:
            h.update(path.relative_to(root).as_posix().encode() + b"\0" + text + b"\0")
    return h.hexdigest()[:16]


def use_kernel_cache(root: Path = PACKAGE) -> Path | None:
    """Point numba's cache at <default_cache_dir>/numba/<sources_digest>, unless $NUMBA_CACHE_DIR is set (then that
    is used as it is); removes the caches of all but the KEEP most recently used other versions. Returns the
    directory, or None when it is left to numba (set by the user, or not writable: numba then caches next to the
    sources, or in the user's cache)."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return None
    base = default_cache_dir() / "numba"
    target = base / sources_digest(root)
    try:
        target.mkdir(parents=True, exist_ok=True)
        os.utime(target)  # the most recently used version
    except OSError:
        return None
    os.environ["NUMBA_CACHE_DIR"] = str(target)  # the planning process and other children too
    numba = sys.modules.get("numba")
    if numba is not None:  # imported before replanner: its config has read the environment already
        numba.config.CACHE_DIR = str(target)
    others = sorted((p for p in base.iterdir() if p.is_dir() and p != target), key=_last_used)
    for old in others[: max(len(others) - KEEP, 0)]:
        shutil.rmtree(old, ignore_errors=True)
    return target


def _last_used(path: Path) -> float:
    try:
        return path.stat().st_mtime
    except OSError:  # removed by another process meanwhile
        return -1.0
