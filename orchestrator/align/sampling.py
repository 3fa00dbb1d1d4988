"""Resampling helpers shared by the temporal methods: low-pass + interpolation, noise scales,
DTW paths to index maps."""
from __future__ import annotations

from itertools import chain

import numpy as np
from scipy.ndimage import uniform_filter1d

from milling_twin.orchestrator.align.trajectory import Trajectory

__all__ = ["axis_noise", "decimate", "local_noise", "lowpass", "mean_match", "sample",
           "storage_step", "uniform_grid"]


def uniform_grid(t0: float, t1: float, n: int) -> np.ndarray:
    return np.linspace(t0, t1, int(n))


def lowpass(values: np.ndarray, width: float) -> np.ndarray:
    """Moving average over ``width`` samples (running sum: O(n) for any width), along axis 0."""
    size = int(round(width))
    if size <= 1:
        return values
    return uniform_filter1d(values, size=size, axis=0, mode="nearest")


def sample(traj: Trajectory, times: np.ndarray, width: float = 0.0) -> np.ndarray:
    """Positions at ``times`` after a moving average ``width`` seconds wide (anti-aliasing for a
    coarser grid); held constant beyond either end of the trajectory."""
    if width <= 0 or width * (len(traj) - 1) < 1.5 * traj.duration:
        return traj.at(times)
    pos = lowpass(traj.position, width * (len(traj) - 1) / traj.duration)
    out = np.empty((np.size(times), 3))
    for a in range(3):
        out[:, a] = np.interp(times, traj.time, np.ascontiguousarray(pos[:, a]))
    return out


def decimate(traj: Trajectory, n: int) -> Trajectory:
    """The trajectory on ``n`` uniform points (moving average over one new step first); the
    trajectory itself if it has no more than ``n`` samples."""
    if len(traj) <= n:
        return traj
    times = uniform_grid(traj.time[0], traj.time[-1], n)
    return Trajectory(times, sample(traj, times, times[1] - times[0]), traj.name)


def axis_noise(position: np.ndarray) -> np.ndarray:
    """Per-axis noise scale of a recorded position signal without knowing the true path: the
    larger of white noise seen in second differences (MAD / sqrt(6)) and the quantization step
    (5th percentile of the non-zero steps) / sqrt(12); at least 1e-6 of the axis range."""
    out = np.empty(3)
    for a in range(3):
        p = position[:, a]
        d1 = np.abs(np.diff(p))
        d2 = np.diff(p, 2)
        white = 1.4826 * np.median(np.abs(d2 - np.median(d2))) / np.sqrt(6) if d2.size else 0.0
        nz = d1[d1 > 1e-12 * max(1.0, float(np.abs(p).max()))]
        quant = float(np.percentile(nz, 5)) / np.sqrt(12) if nz.size else 0.0
        span = float(np.ptp(p))
        out[a] = max(white, quant, 1e-6 * span, 1e-12)
    return out


def storage_step(position: np.ndarray) -> np.ndarray:
    """Per-sample, per-axis storage step (n, 3), 0 where the values are not stored rounded.

    The step may depend on the value (3 significant digits: 1 mm from 100 mm on, 0.1 mm from
    10 mm): for each axis and each decade of ``|value|``, the step is the smallest difference
    between distinct values in that decade, and it counts only if (nearly) all values there are
    whole multiples of it."""
    n = position.shape[0]
    out = np.zeros((n, 3))
    for a in range(3):
        p = position[:, a]
        decade = np.floor(np.log10(np.maximum(np.abs(p), 1e-300)))
        for d in np.unique(decade):
            sel = decade == d
            values = np.unique(p[sel])
            if values.size < 2 or values.size > 0.5 * sel.sum():
                continue
            q = float(np.min(np.diff(values)))
            ratio = values / q
            if np.mean(np.abs(ratio - np.round(ratio)) < 1e-6) >= 0.99:
                out[sel, a] = q
    return out


def local_noise(position: np.ndarray, step: np.ndarray | None = None) -> np.ndarray:
    """Per-sample, per-axis noise scale (n, 3): the storage step (:func:`storage_step`)
    / sqrt(12), at least the axis' white noise (MAD of second differences / sqrt(6)) and 1e-6
    of its range."""
    q = storage_step(position) if step is None else step
    out = np.empty_like(q)
    for a in range(3):
        p = position[:, a]
        d2 = np.diff(p, 2)
        white = 1.4826 * np.median(np.abs(d2 - np.median(d2))) / np.sqrt(6) if d2.size else 0.0
        out[:, a] = np.maximum(np.maximum(q[:, a] / np.sqrt(12), white),
                               max(1e-6 * float(np.ptp(p)), 1e-12))
    return out


def mean_match(path: list[tuple[int, int]], n: int) -> np.ndarray:
    """For a DTW warping path (pairs i, j), the mean j of each i in 0..n-1; rows the path
    leaves out (relaxed ends) get the nearest row's value."""
    flat = np.fromiter(chain.from_iterable(path), dtype=np.int64, count=2 * len(path))
    ij = flat.reshape(-1, 2)
    count = np.bincount(ij[:, 0], minlength=n)[:n]
    total = np.bincount(ij[:, 0], weights=ij[:, 1].astype(np.float64), minlength=n)[:n]
    jbar = total / np.maximum(count, 1)
    missing = count == 0  # a relaxed (psi) end may leave the last rows out of the path
    if missing.any():
        have = np.flatnonzero(~missing)
        jbar[missing] = np.interp(np.flatnonzero(missing), have, jbar[have])
    return jbar
