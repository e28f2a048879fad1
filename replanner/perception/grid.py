"""Log-odds occupancy over the workspace grid: hits, misses from seeing through a voxel, clamping and decay.

Only voxels with positive evidence are tracked (`active`); unknown and free space both read as free, as in
OctoMap-based planners. A voxel is occupied while its log-odds is > 0, so one hit makes it occupied at once
(react to a new obstacle within one frame) and `ceil(clamp_max / -miss)` frames of seeing through it clear it.
"""

from __future__ import annotations

import math

import numpy as np

from ..sections import OccupancyUpdateConfig
from .filters import VoxelGrid
from .kernels import in_sorted, union_sorted


class LogOddsGrid:
    """Per-voxel log-odds and last-hit time over a `VoxelGrid`; `active` = sorted flat indices of occupied voxels."""

    def __init__(self, grid: VoxelGrid, cfg: OccupancyUpdateConfig):
        self.grid = grid
        self.cfg = cfg
        # np.full writes every page now; np.zeros would page-fault on first touch, mid-frame
        self.logodds = np.full(grid.size, 0.0, dtype=np.float32)
        self.last_hit = np.full(grid.size, 0.0, dtype=np.float64)
        self.active = np.zeros(0, dtype=np.int64)

    @property
    def frames_to_clear(self) -> int:
        """Frames of seeing through a voxel that clear it from the clamp (the clearing bound)."""
        return math.ceil(self.cfg.clamp_max / -self.cfg.miss - 1e-9)

    def update(self, hits: np.ndarray, misses: np.ndarray, stamp: float, shadow: np.ndarray | None = None) -> None:
        """Apply one frame: `hits` and `misses` are unique flat indices; a voxel in both counts as hit.

        `shadow`: voxels hidden just behind the hits; they count as hits (occluded space next to a surface).
        """
        if shadow is not None and len(shadow):
            hits = union_sorted(hits, shadow)
        lo = self.logodds
        if len(misses):
            lo[misses] += self.cfg.miss
        if len(hits):
            lo[hits] = np.minimum(lo[hits] + self.cfg.hit, self.cfg.clamp_max)
            self.last_hit[hits] = stamp
        merged = union_sorted(self.active, hits) if len(hits) else self.active
        keep = lo[merged] > 0.0
        gone = merged[~keep]
        lo[gone] = 0.0  # back to unknown: the next hit makes it occupied again at once
        self.active = merged[keep]

    def decay(self, now: float) -> int:
        """Drop occupied voxels not hit for `decay_after` seconds (those no sensor sees any more). Returns count."""
        if self.cfg.decay_after is None or not len(self.active):
            return 0
        old = now - self.last_hit[self.active] > self.cfg.decay_after
        if old.any():
            self.logodds[self.active[old]] = 0.0
            self.active = self.active[~old]
        return int(old.sum())

    def forget(self, flat: np.ndarray) -> None:
        """Drop these voxels (e.g. inside an object the world now knows): unknown again."""
        self.logodds[flat] = 0.0
        self.active = self.active[~in_sorted(self.active, np.sort(flat))]

    def clear(self) -> None:
        self.logodds[self.active] = 0.0
        self.active = np.zeros(0, dtype=np.int64)
