"""The result of every temporal alignment method: a monotonic map recorded time -> simulated time.

``TimeMap.simulated_time[i]`` is the moment of the simulation (seconds on the simulation's own
clock) at which the machine was where recorded sample ``i`` (at ``recorded_time[i]``) shows it.
The map is non-decreasing: it is flat where the machine paused and the simulation did not; it
jumps (steep) where the simulation dwelt and the machine did not. ``confidence[i]`` in [0, 1]
says how well sample ``i`` is determined (see :mod:`milling_twin.orchestrator.align.refine` for the measure of
the multiscale method; each method documents its own).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from milling_twin.orchestrator.align.errors import AlignmentError
from milling_twin.orchestrator.align.trajectory import Trajectory

__all__ = ["PathResidual", "TimeMap", "path_residual"]


def _interp_columns(x: np.ndarray, xp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    fp = np.asarray(fp, dtype=np.float64)
    if fp.shape[0] != xp.size:
        raise AlignmentError(f"values have {fp.shape[0]} rows but the time axis has {xp.size}")
    if fp.ndim == 1:
        return np.interp(x, xp, fp)
    flat = fp.reshape(xp.size, -1)
    out = np.stack([np.interp(x, xp, flat[:, k]) for k in range(flat.shape[1])], axis=-1)
    return out.reshape(x.shape + fp.shape[1:])


@dataclass(frozen=True)
class TimeMap:
    """``recorded_time`` (N,) strictly increasing; ``simulated_time`` (N,) non-decreasing;
    ``confidence`` (N,) in [0, 1]; ``method`` that made it; ``info``: method details."""

    recorded_time: np.ndarray
    simulated_time: np.ndarray
    confidence: np.ndarray
    method: str
    info: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        rt = np.ascontiguousarray(self.recorded_time, dtype=np.float64)
        st = np.ascontiguousarray(self.simulated_time, dtype=np.float64)
        cf = np.ascontiguousarray(self.confidence, dtype=np.float64)
        if not (rt.ndim == 1 and rt.shape == st.shape == cf.shape and rt.size >= 2):
            raise AlignmentError(f"TimeMap ({self.method}): recorded_time, simulated_time and "
                                 f"confidence must be 1-D of one length >= 2, got {rt.shape}, "
                                 f"{st.shape}, {cf.shape}")
        for label, arr in (("recorded_time", rt), ("simulated_time", st), ("confidence", cf)):
            if not np.all(np.isfinite(arr)):
                raise AlignmentError(f"TimeMap ({self.method}): {label} is not finite at row "
                                     f"{int(np.argmax(~np.isfinite(arr)))}")
        if np.any(np.diff(rt) <= 0):
            raise AlignmentError(f"TimeMap ({self.method}): recorded_time must be strictly "
                                 f"increasing (row {int(np.argmax(np.diff(rt) <= 0)) + 1})")
        if np.any(np.diff(st) < 0):
            raise AlignmentError(f"TimeMap ({self.method}): simulated_time must be "
                                 f"non-decreasing (row {int(np.argmax(np.diff(st) < 0)) + 1})")
        if np.any((cf < 0) | (cf > 1)):
            raise AlignmentError(f"TimeMap ({self.method}): confidence must lie in [0, 1]")
        object.__setattr__(self, "recorded_time", rt)
        object.__setattr__(self, "simulated_time", st)
        object.__setattr__(self, "confidence", cf)

    def __len__(self) -> int:
        return int(self.recorded_time.size)

    def to_simulated(self, recorded_time: np.ndarray | float) -> np.ndarray:
        """Simulated time of arbitrary recorded times (linear between samples); NaN outside
        ``[recorded_time[0], recorded_time[-1]]``."""
        q = np.asarray(recorded_time, dtype=np.float64)
        out = np.interp(q, self.recorded_time, self.simulated_time)
        return np.where((q >= self.recorded_time[0]) & (q <= self.recorded_time[-1]), out, np.nan)

    def to_recorded(self, simulated_time: np.ndarray | float) -> np.ndarray:
        """Recorded time at which the machine reached each simulated moment: where the map is
        flat (a pause of the machine) the *first* recorded time of the flat part; linear between
        samples otherwise; NaN outside ``[simulated_time[0], simulated_time[-1]]``."""
        q = np.asarray(simulated_time, dtype=np.float64)
        s, t = self.simulated_time, self.recorded_time
        first = np.searchsorted(s, q, side="left")  # first sample with s >= q
        hit = s[np.clip(first, 0, s.size - 1)] == q
        k = np.clip(first, 1, s.size - 1)
        s0, s1, t0, t1 = s[k - 1], s[k], t[k - 1], t[k]
        frac = np.divide(q - s0, s1 - s0, out=np.ones_like(q, dtype=np.float64), where=s1 > s0)
        out = np.where(hit, t[np.clip(first, 0, s.size - 1)],
                       t0 + np.clip(frac, 0.0, 1.0) * (t1 - t0))
        return np.where((q >= s[0]) & (q <= s[-1]), out, np.nan)

    def resample_simulated(self, simulated_time: np.ndarray, values: np.ndarray) -> np.ndarray:
        """A simulated channel (``values`` with one row per ``simulated_time``) at every recorded
        sample: ``values(simulated_time[i])``, linear; NaN where the map leaves the channel's
        time range."""
        st = np.asarray(simulated_time, dtype=np.float64)
        out = _interp_columns(self.simulated_time, st, values)
        outside = (self.simulated_time < st[0]) | (self.simulated_time > st[-1])
        if outside.any():
            out = np.array(out, dtype=np.float64)
            out[outside] = np.nan
        return out

    def resample_recorded(self, values: np.ndarray, simulated_time: np.ndarray) -> np.ndarray:
        """A recorded channel (``values``, one row per recorded sample) at the given simulated
        times (the reverse direction, through :meth:`to_recorded`); NaN where undefined."""
        rt = self.to_recorded(simulated_time)
        valid = np.isfinite(rt)
        out = _interp_columns(np.where(valid, rt, self.recorded_time[0]), self.recorded_time,
                              values)
        out = np.array(out, dtype=np.float64)
        out[~valid] = np.nan
        return out

    def frame(self) -> pd.DataFrame:
        return pd.DataFrame({"recorded_time": self.recorded_time,
                             "simulated_time": self.simulated_time,
                             "confidence": self.confidence})


@dataclass(frozen=True)
class PathResidual:
    """Distance between each recorded position and the simulated position at its mapped time."""

    distance: np.ndarray
    median: float
    p95: float
    rms: float
    max: float
    samples: int


def path_residual(time_map: TimeMap, recorded: Trajectory, simulated: Trajectory,
                  min_confidence: float = 0.0) -> PathResidual:
    """Residual path error after alignment: |p_rec(t_i) - p_sim(map(t_i))| over the samples with
    ``confidence >= min_confidence`` (the distance array holds all samples)."""
    if recorded.time.shape != time_map.recorded_time.shape or not np.array_equal(
            recorded.time, time_map.recorded_time):
        raise AlignmentError(f"{recorded.name}: the time map was not made for this recording "
                             f"({len(recorded)} samples, map has {len(time_map)})")
    sim = time_map.resample_simulated(simulated.time, simulated.position)
    dist = np.linalg.norm(recorded.position - sim, axis=1)
    use = (time_map.confidence >= min_confidence) & np.isfinite(dist)
    if not use.any():
        raise AlignmentError(f"{recorded.name}: no sample has confidence >= {min_confidence}")
    d = dist[use]
    return PathResidual(dist, float(np.median(d)), float(np.percentile(d, 95)),
                        float(np.sqrt(np.mean(d ** 2))), float(d.max()), int(d.size))
