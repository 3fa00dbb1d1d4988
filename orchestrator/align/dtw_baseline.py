"""Baseline: plain DTW of the 3-D positions with dtaidistance (its C implementation).

The simulated path is resampled on a uniform grid at the recorded median period, the recorded
samples are taken as they are, and ``dtaidistance.dtw_ndim.warping_path`` (squared Euclidean
point cost, symmetric steps) pairs them; a recorded sample's simulated time is the mean time of
the grid points it is paired with. Without ``window`` the full N x M cost matrix is kept (memory
8*N*M bytes); ``window`` is dtaidistance's diagonal band. Confidence as in
:func:`milling_twin.orchestrator.align.refine.confidence` (residual and motion), without refinement.
"""
from __future__ import annotations

import time as _time
from dataclasses import asdict, dataclass

import numpy as np
from dtaidistance import dtw_ndim

from milling_twin.orchestrator.align.errors import AlignmentError
from milling_twin.orchestrator.align.refine import confidence
from milling_twin.orchestrator.align.sampling import mean_match
from milling_twin.orchestrator.align.timemap import TimeMap
from milling_twin.orchestrator.align.trajectory import Trajectory

__all__ = ["DtwOptions", "align_dtw"]


@dataclass(frozen=True)
class DtwOptions:
    """``window``: dtaidistance band (None: full matrix); ``psi``: free start/end on the
    simulated side (samples); ``max_cells``: refuse larger N x M (memory) problems."""

    window: int | None = None
    psi: int = 0
    max_cells: float = 2.5e9


def align_dtw(recorded: Trajectory, simulated: Trajectory,
              options: DtwOptions = DtwOptions()) -> TimeMap:
    start = _time.perf_counter()
    dt = float(np.median(np.diff(recorded.time)))
    grid = np.arange(simulated.time[0], simulated.time[-1] + 0.5 * dt, dt)
    a_seq = np.ascontiguousarray(recorded.position)
    b_seq = np.ascontiguousarray(simulated.at(grid))
    n, m = len(a_seq), len(b_seq)
    cells = float(n) * m if not options.window else float(n) * (2 * options.window + abs(n - m))
    if cells > options.max_cells:
        raise AlignmentError(f"dtw baseline: {n} x {m} samples need {cells:.3g} matrix cells "
                             f"({8 * cells / 2**30:.1f} GiB), more than max_cells "
                             f"{options.max_cells:.3g}")
    psi = (0, 0, options.psi, options.psi) if options.psi else None
    path = dtw_ndim.warping_path(a_seq, b_seq, window=options.window, psi=psi, use_c=True)
    tau = np.maximum.accumulate(np.interp(mean_match(path, n), np.arange(m), grid))
    sim_pos = simulated.at(tau)
    vel = np.stack([np.interp(tau, simulated.time, v) for v in simulated.velocity().T], axis=1)
    res = recorded.position - sim_pos
    sigma = np.maximum(1.4826 * np.median(np.abs(res - np.median(res, axis=0)), axis=0),
                       1e-9 * (1.0 + np.ptp(simulated.position, axis=0)))
    conf = confidence(res, vel, sigma, dt)
    return TimeMap(recorded.time, tau, conf, "dtw",
                   {"options": asdict(options), "cells": cells,
                    "wall_time": _time.perf_counter() - start})
