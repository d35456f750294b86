"""A fixed family of throws around a nominal one: the closed loop's test and benchmark set.

Throw k starts at p0 + δp, v0 + δv with δp uniform in ±``SPREAD_P`` [m] and δv uniform in ±``SPREAD_V`` [m/s] per
coordinate, drawn from ``numpy.random.default_rng(SEED + k)``: the same throws on every machine.
"""
from __future__ import annotations

import numpy as np

from hoc_cli.realtime.loop import Throw

SEED = 100
SPREAD_P = 0.02
SPREAD_V = 0.1


def family(p0, v0, count: int, gravity=(0.0, 0.0, -9.81)) -> list[Throw]:
    """``count`` throws around (p0 (3,) [m], v0 (3,) [m/s]) (module docstring)."""
    out = []
    for k in range(count):
        rng = np.random.default_rng(SEED + k)
        out.append(Throw(np.asarray(p0, float) + rng.uniform(-SPREAD_P, SPREAD_P, 3),
                         np.asarray(v0, float) + rng.uniform(-SPREAD_V, SPREAD_V, 3), np.asarray(gravity, float)))
    return out
