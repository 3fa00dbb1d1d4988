"""Tool positions over time: the input of every temporal alignment method.

A :class:`Trajectory` is ``time`` (s, strictly increasing) and ``position`` (n x 3: x, y, z,
any one length unit, the same for the recorded and the simulated side; the loaders below keep
the project's SI metres).

Output-delay convention of co-simulation results (:func:`milling_twin.orchestrator.results.load_results`):
the row at ``time = t`` holds the outputs *as left by the doStep that ended at t*, i.e. the step
``doStep(t - h, h)``; the first row (``t = start``) holds the values after initialization.

* A state-like output (the interpolator's tool position, a model's integrated state) is the
  value *at* t: use it as it is (``output_delay = 0``).
* An output computed from inputs that the master sampled at the start of the step (recorded
  channels are sampled at ``t - h``; an algebraic feed-through such as ``P_total`` of the
  spindle-power FMU) describes the moment ``t - h``: pass ``output_delay = h``. The rows are then
  shifted back by h and the first row, which is the initial value and not a step result, is
  dropped.

``tests/test_align_temporal.py::test_output_delay_convention_of_cosimulation_results`` runs the
master and checks both statements.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from milling_twin.orchestrator.align.errors import AlignmentError
from milling_twin.orchestrator.recorded import RecordedData

__all__ = ["Trajectory", "delay_corrected"]


def delay_corrected(results: pd.DataFrame, output_delay: float,
                    name: str = "results") -> pd.DataFrame:
    """``results`` with ``time`` moved back by ``output_delay`` seconds and, if that is > 0,
    without the first row (the initial values, not a step result); see the module text."""
    if "time" not in results.columns:
        raise AlignmentError(f"{name}: no column 'time'; columns: {list(results.columns)}")
    if (isinstance(output_delay, bool) or not isinstance(output_delay, (int, float))
            or not math.isfinite(output_delay) or output_delay < 0):
        raise AlignmentError(f"{name}: output_delay must be a finite number of seconds >= 0, "
                             f"got {output_delay!r}")
    if output_delay == 0:
        return results
    out = results.iloc[1:].copy()
    out["time"] = out["time"] - output_delay
    return out.reset_index(drop=True)


@dataclass(frozen=True)
class Trajectory:
    """``time`` (n,) seconds, strictly increasing, n >= 2; ``position`` (n, 3), finite.

    ``name`` says where the data came from; every error message starts with it."""

    time: np.ndarray
    position: np.ndarray
    name: str = "trajectory"

    def __post_init__(self) -> None:
        time = np.ascontiguousarray(self.time, dtype=np.float64)
        pos = np.ascontiguousarray(self.position, dtype=np.float64)
        if time.ndim != 1 or time.size < 2:
            raise AlignmentError(f"{self.name}: time must be 1-D with at least 2 samples, "
                                 f"got shape {time.shape}")
        if pos.ndim == 1:
            pos = pos[:, None]
        if pos.shape != (time.size, 3):
            raise AlignmentError(f"{self.name}: position must have shape ({time.size}, 3) "
                                 f"(x, y, z per time sample), got {pos.shape}")
        bad_t = ~np.isfinite(time)
        if bad_t.any():
            raise AlignmentError(f"{self.name}: time is not finite at row {int(np.argmax(bad_t))}")
        bad = ~np.isfinite(pos)
        if bad.any():
            row, col = np.argwhere(bad)[0]
            raise AlignmentError(f"{self.name}: position is not finite at row {row}, axis "
                                 f"{'xyz'[col]} ({float(pos[row, col])!r})")
        steps = np.diff(time)
        if np.any(steps <= 0):
            i = int(np.argmax(steps <= 0))
            raise AlignmentError(f"{self.name}: time must be strictly increasing, but row {i + 1} "
                                 f"({float(time[i + 1])!r} s) follows row {i} ({float(time[i])!r} s)")
        object.__setattr__(self, "time", time)
        object.__setattr__(self, "position", pos)
        # contiguous columns: np.interp copies a strided column on every call otherwise
        object.__setattr__(self, "_columns", tuple(np.ascontiguousarray(pos[:, a])
                                                   for a in range(3)))

    def __len__(self) -> int:
        return int(self.time.size)

    @property
    def duration(self) -> float:
        return float(self.time[-1] - self.time[0])

    def at(self, t: np.ndarray) -> np.ndarray:
        """Positions at times ``t`` (linear interpolation, held constant beyond either end)."""
        t = np.asarray(t, dtype=np.float64)
        out = np.empty(t.shape + (3,))
        for a, col in enumerate(self._columns):  # type: ignore[attr-defined]
            out[..., a] = np.interp(t, self.time, col)
        return out

    def velocity(self) -> np.ndarray:
        """Velocity (n, 3) in length unit per second, by central differences."""
        return np.gradient(self.position, self.time, axis=0)

    @classmethod
    def from_arrays(cls, time: Sequence[float] | np.ndarray, x: Sequence[float] | np.ndarray,
                    y: Sequence[float] | np.ndarray, z: Sequence[float] | np.ndarray,
                    name: str = "trajectory") -> Trajectory:
        arrays = [np.asarray(a, dtype=np.float64) for a in (x, y, z)]
        sizes = {a.shape for a in arrays} | {np.shape(time)}
        if len(sizes) != 1:
            raise AlignmentError(f"{name}: time, x, y, z must have the same shape, got "
                                 f"{[np.shape(time)] + [a.shape for a in arrays]}")
        return cls(np.asarray(time, dtype=np.float64), np.stack(arrays, axis=1), name)

    @classmethod
    def from_recorded(cls, recorded: RecordedData,
                      channels: Sequence[str] = ("x", "y", "z")) -> Trajectory:
        """The three position channels of a recording (SI units as loaded)."""
        if len(channels) != 3:
            raise AlignmentError(f"{recorded.path}: give 3 position channels (x, y, z), "
                                 f"got {list(channels)}")
        missing = [c for c in channels if c not in recorded.channels]
        if missing:
            raise AlignmentError(f"{recorded.path}: no channel {missing[0]!r}; channels: "
                                 f"{sorted(recorded.channels)}")
        for c in channels:
            if recorded.units[c] == "bool":
                raise AlignmentError(f"{recorded.path}: channel {c!r} is boolean, not a position")
        pos = np.stack([recorded.channels[c] for c in channels], axis=1)
        return cls(recorded.time, pos, str(recorded.path))

    @classmethod
    def from_results(cls, results: pd.DataFrame, columns: Sequence[str],
                     output_delay: float = 0.0, name: str = "results") -> Trajectory:
        """Positions from a results table (:func:`milling_twin.orchestrator.results.load_results`): column
        ``time`` and the three position ``columns``. See the module text for ``output_delay``."""
        if len(columns) != 3:
            raise AlignmentError(f"{name}: give 3 position columns (x, y, z), got {list(columns)}")
        for c in ["time", *columns]:
            if c not in results.columns:
                raise AlignmentError(f"{name}: no column {c!r}; columns: {list(results.columns)}")
        shifted = delay_corrected(results, output_delay, name)
        time = shifted["time"].to_numpy(dtype=np.float64)
        pos = shifted[list(columns)].to_numpy(dtype=np.float64)
        return cls(time, pos, name)
