"""Recorded samples paired with the co-simulation rows of the same machining moment.

Each recorded sample i (time t_i) is mapped to a simulated time s_i: the identity (method
"none") or a :class:`~orchestrator.align.TimeMap` from :func:`milling_twin.orchestrator.align.align_results`
on the channels the spec names. The results row time is ``s_i + output_delay`` (the alignment
works on delay-corrected simulated time, see orchestrator.align.trajectory). At that time the
model's data columns are taken from the rows (real values linear between rows, booleans from
the nearest row); dynamic models use the nearest row index. Samples whose simulated time falls
outside the run, outside the consistent segments of a checked recording (``[recorded.checks]``; the first
sample of a segment too, :meth:`RecordedData.consistent`) or whose alignment confidence is below
``min_confidence``, are not used; an alignment
whose median confidence is below ``refuse_below`` has failed, and calibration stops with a CalibrationError
naming the recording, the segment and the confidence (:func:`refuse_failed_alignment`).
"""
from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from milling_twin.orchestrator.align import TimeMap, align_results
from milling_twin.orchestrator.align.segments import segment_confidence
from milling_twin.orchestrator.calibrate.errors import CalibrationError
from milling_twin.orchestrator.calibrate.spec import AlignmentSpec
from milling_twin.orchestrator.recorded import RecordedData

__all__ = ["AlignmentSummary", "Pairs", "at_rows", "make_pairs", "map_times", "refuse_failed_alignment"]

LEARNING, VALIDATION = 0, 1


@dataclass(frozen=True)
class Pairs:
    recorded_time: np.ndarray  # (n,)
    row_time: np.ndarray  # (n,) time of the results rows the sample is paired with
    confidence: np.ndarray  # (n,)
    recorded: np.ndarray  # (n, outputs), in each output's SI unit
    data: np.ndarray  # (n, data columns), the model's data at the pair
    rows: np.ndarray  # (n,) nearest row index
    fmu: np.ndarray  # (n, outputs) the FMU's outputs at the pair
    segment: np.ndarray  # (n,) LEARNING, VALIDATION or -1

    def __len__(self) -> int:
        return int(self.recorded_time.size)

    def select(self, segment: int) -> "Pairs":
        keep = self.segment == segment
        return Pairs(*(getattr(self, f)[keep] for f in self.__dataclass_fields__))

    def with_fmu(self, results: pd.DataFrame, outputs: Sequence[str]) -> "Pairs":
        """The same pairs with the FMU outputs taken from another run on the same grid."""
        return replace(self, fmu=at_rows(results, outputs, self.row_time))


@dataclass(frozen=True)
class AlignmentSummary:
    method: str
    recorded_samples: int
    paired: int
    learning: int
    validation: int
    max_shift: float  # max |row time - output delay - recorded time|, s
    median_shift: float
    p95_shift: float
    median_confidence: float
    wall_time: float


def at_rows(results: pd.DataFrame, columns: Sequence[str], times: np.ndarray) -> np.ndarray:
    t = results["time"].to_numpy(dtype=float)
    out = np.empty((times.size, len(columns)))
    nearest = np.clip(np.searchsorted(t, times), 1, t.size - 1)
    nearest -= (times - t[nearest - 1]) < (t[nearest] - times)
    for k, c in enumerate(columns):
        values = results[c].to_numpy()
        if values.dtype == bool:
            out[:, k] = values[nearest].astype(float)
        else:
            out[:, k] = np.interp(times, t, values.astype(float))
    return out


def refuse_failed_alignment(recorded: RecordedData, time_map: TimeMap, alignment: AlignmentSpec,
                            segment: int = 0, rows: tuple[int, int] | None = None) -> None:
    """A CalibrationError when the alignment's confidence (the median over its samples, as
    orchestrator.align.segments measures a segment) is below ``[alignment].refuse_below``: its pairs
    would fit garbage. The whole recording is segment 0 unless ``segment`` and ``rows`` say otherwise."""
    confidence = segment_confidence(time_map.confidence)
    if confidence < alignment.refuse_below:
        first, last = rows if rows is not None else (0, len(time_map) - 1)
        raise CalibrationError(
            f"{recorded.path}: segment {segment} (rows {first}-{last}): alignment confidence {confidence:.2f} is "
            f"below [alignment].refuse_below = {alignment.refuse_below:g}; the alignment failed, no pairs are "
            "made from it (check the simulated run and the recording, e.g. milling-twin align temporal)")


def map_times(recorded: RecordedData, results: pd.DataFrame, alignment: AlignmentSpec) -> tuple[np.ndarray, np.ndarray, TimeMap | None]:
    """(row time per recorded sample, confidence, the TimeMap or None for method "none")."""
    if alignment.method == "none":
        return recorded.time.copy(), np.ones(recorded.time.size), None
    time_map = align_results(recorded, results, [str(r) for r in alignment.simulated], list(alignment.recorded),
                             method=alignment.method, output_delay=alignment.output_delay)
    refuse_failed_alignment(recorded, time_map, alignment)
    return time_map.simulated_time + alignment.output_delay, time_map.confidence, time_map


def make_pairs(recorded: RecordedData, results: pd.DataFrame, data_columns: Sequence[str], outputs: Sequence[str],
               channels: Sequence[str], factors: Sequence[float], alignment: AlignmentSpec,
               learning: Sequence[tuple[float, float]], validation: Sequence[tuple[float, float]]
               ) -> tuple[Pairs, AlignmentSummary, TimeMap | None]:
    """Pairs for ``outputs`` ("instance.variable") against ``channels`` (recorded value * factor = output
    unit), with the model's ``data_columns`` (the inputs the models/ graph reads; none on the FMU path)."""
    t0 = time.perf_counter()
    row_time, confidence, time_map = map_times(recorded, results, alignment)
    t = results["time"].to_numpy(dtype=float)
    inside = ((row_time >= t[0] - 1e-9) & (row_time <= t[-1] + 1e-9) & (confidence >= alignment.min_confidence)
              & recorded.consistent(recorded.time))
    rt = np.clip(row_time[inside], t[0], t[-1])
    rec_t = recorded.time[inside]
    rec = np.column_stack([recorded.channels[c][inside].astype(float) * f for c, f in zip(channels, factors)])
    data = at_rows(results, list(data_columns), rt) if data_columns else np.zeros((rt.size, 0))
    rows = np.clip(np.searchsorted(t, rt), 1, t.size - 1)
    rows -= (rt - t[rows - 1]) < (t[rows] - rt)
    segment = np.full(rt.size, -1)
    for code, windows in ((LEARNING, learning), (VALIDATION, validation)):
        for a, b in windows:
            segment[(rec_t >= a) & (rec_t <= b)] = code
    pairs = Pairs(rec_t, rt, confidence[inside], rec, data, rows, at_rows(results, list(outputs), rt), segment)
    shift = np.abs(rt - alignment.output_delay - rec_t) if alignment.method != "none" else np.zeros(rt.size)
    summary = AlignmentSummary(
        alignment.method, int(recorded.time.size), int(rt.size), int((segment == LEARNING).sum()),
        int((segment == VALIDATION).sum()), float(shift.max()) if shift.size else 0.0,
        float(np.median(shift)) if shift.size else 0.0, float(np.percentile(shift, 95)) if shift.size else 0.0,
        float(np.median(confidence[inside])) if rt.size else 0.0, time.perf_counter() - t0)
    return pairs, summary, time_map
