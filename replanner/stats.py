"""Summary statistics every benchmark prints the same way."""

from __future__ import annotations

import numpy as np


def summary(values) -> dict:
    """{"median", "p95", "n"} of a sample (NaN-free); rounded for printing."""
    a = np.asarray(values, dtype=float)
    if a.size == 0:
        return {"median": None, "p95": None, "n": 0}
    return {"median": round(float(np.median(a)), 3), "p95": round(float(np.percentile(a, 95)), 3), "n": int(a.size)}
