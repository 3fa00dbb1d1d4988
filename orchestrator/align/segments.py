"""Per-segment temporal alignment joined into one piecewise time map, and the confidence threshold.

A recording cut into consistent segments (:mod:`milling_twin.orchestrator.recording_checks`, policy
``segment``) is simulated one segment at a time (``milling-twin reconstruct`` writes one program per
segment). :func:`align_segments` aligns each segment's recorded positions with the simulated run of its
program (:func:`milling_twin.orchestrator.align.align`) and joins the maps into a :class:`PiecewiseTimeMap`:
one row per recorded sample with its segment index and the simulated time on that segment's own clock
(it resets at each segment start, where the segment's run starts).

A segment's confidence is the median of its samples' confidences. Below ``min_confidence``
(:data:`DEFAULT_MIN_CONFIDENCE` unless given) the alignment of that segment has failed: ``milling-twin align
temporal`` lists such segments and calibration refuses pairs from them (orchestrator/calibrate/pairing.py).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from milling_twin.orchestrator.align.errors import AlignmentError
from milling_twin.orchestrator.align.refine import confidence
from milling_twin.orchestrator.align.sampling import local_noise, storage_step
from milling_twin.orchestrator.align.temporal import align
from milling_twin.orchestrator.align.timemap import TimeMap
from milling_twin.orchestrator.align.trajectory import Trajectory

__all__ = ["DEFAULT_MIN_CONFIDENCE", "PiecewiseTimeMap", "SegmentMap", "align_segments", "segment_confidence"]

#: median confidence of a segment below which its alignment is taken as failed. A correct alignment of the
#: UMich segments scores 0.6-1.0 (cutting at 6 mm/s moves two storage steps per sample); one against the
#: wrong path or a wrong time scale scores 0.0-0.1 (residuals of many storage steps)
DEFAULT_MIN_CONFIDENCE = 0.3


def segment_confidence(confidence: np.ndarray) -> float:
    """The confidence of a segment: the median of its samples' (0 without samples)."""
    confidence = np.asarray(confidence, dtype=float)
    return float(np.median(confidence)) if confidence.size else 0.0


@dataclass(frozen=True)
class SegmentMap:
    """Recorded rows ``start`` .. ``stop - 1`` of segment ``index``: its time map (None where it could not be
    aligned: ``reason`` says why)."""

    index: int
    start: int
    stop: int
    time_map: TimeMap | None
    reason: str = ""

    @property
    def confidence(self) -> float:
        return segment_confidence(self.time_map.confidence) if self.time_map is not None else 0.0


@dataclass(frozen=True)
class PiecewiseTimeMap:
    """Time maps of the segments of one recording of ``n_rows`` rows, in row order."""

    n_rows: int
    segments: tuple[SegmentMap, ...]
    name: str = "recording"

    def frame(self) -> pd.DataFrame:
        """One row per aligned recorded sample: row, segment, recorded_time, simulated_time (the segment's
        clock, reset at its start), confidence."""
        parts = []
        for s in self.segments:
            if s.time_map is None:
                continue
            tm = s.time_map
            parts.append(pd.DataFrame({"row": np.arange(s.start, s.stop), "segment": s.index,
                                       "recorded_time": tm.recorded_time, "simulated_time": tm.simulated_time,
                                       "confidence": tm.confidence}))
        if not parts:
            return pd.DataFrame(columns=["row", "segment", "recorded_time", "simulated_time", "confidence"])
        return pd.concat(parts, ignore_index=True)

    def confidence(self) -> np.ndarray:
        """Per recorded row: its confidence, 0 outside the aligned segments."""
        out = np.zeros(self.n_rows)
        for s in self.segments:
            if s.time_map is not None:
                out[s.start:s.stop] = s.time_map.confidence
        return out

    def below(self, min_confidence: float = DEFAULT_MIN_CONFIDENCE) -> list[SegmentMap]:
        """The segments whose alignment failed: confidence below ``min_confidence`` or not aligned."""
        return [s for s in self.segments if s.time_map is None or s.confidence < min_confidence]

    def report(self, min_confidence: float = DEFAULT_MIN_CONFIDENCE) -> list[str]:
        """Lines naming every segment below the threshold, after a summary line."""
        bad = self.below(min_confidence)
        conf = [s.confidence for s in self.segments]
        lines = [f"{self.name}: {len(self.segments)} segments, median segment confidence "
                 f"{np.median(conf) if conf else 0.0:.2f}; {len(bad)} below min_confidence {min_confidence:g}"]
        for s in bad:
            why = s.reason or f"confidence {s.confidence:.2f} < {min_confidence:g}"
            lines.append(f"  segment {s.index} (rows {s.start}-{s.stop - 1}): {why}")
        return lines


def _from_offset(rec: Trajectory, sim: Trajectory, offset: float) -> TimeMap:
    """The map simulated = recorded - offset (a program that reproduces the recorded timing and starts at
    recorded time ``offset``), clipped to the run, with the multiscale method's confidence measure
    (:func:`milling_twin.orchestrator.align.refine.confidence`)."""
    tau = np.clip(rec.time - offset, sim.time[0], sim.time[-1])
    step = storage_step(rec.position)
    sigma = local_noise(rec.position, step)
    velocity = np.stack([np.interp(tau, sim.time, v) for v in sim.velocity().T], axis=1)
    residual = rec.position - sim.at(tau)
    period = float(np.median(np.diff(rec.time)))
    return TimeMap(rec.time, tau, confidence(residual, velocity, sigma, period), "offset", {"offset": offset})


def align_segments(recorded: Trajectory, segments: Sequence[tuple[Any, ...]],
                   method: str = "multiscale", options: Any | None = None) -> PiecewiseTimeMap:
    """Align each ``(index, start, stop, simulated[, offset])`` segment: the recorded rows ``start`` ..
    ``stop - 1`` against ``simulated`` (the run of that segment's program, its own clock; None: no program).
    ``offset``: the recorded time at which the segment's program starts, when it reproduces the recorded
    timing (``milling-twin reconstruct``'s segment programs start at the segment's first motion): the map
    recorded - offset is also tried, and of the two the map of the higher segment confidence is
    kept (``method`` alone needs more samples than a segment of ten rows has). A segment that cannot be
    aligned gets no map and the reason (its confidence is 0)."""
    out = []
    for index, start, stop, simulated, *rest in segments:
        offset = rest[0] if rest else None
        if simulated is None:
            out.append(SegmentMap(index, start, stop, None, "no simulated run (no program)"))
            continue
        if stop - start < 2:
            out.append(SegmentMap(index, start, stop, None, "fewer than 2 rows"))
            continue
        rec = Trajectory(recorded.time[start:stop], recorded.position[start:stop],
                         f"{recorded.name} segment {index}")
        maps, errors = [], []
        for make in (lambda: align(rec, simulated, method, options),
                     lambda: _from_offset(rec, simulated, offset) if offset is not None else None):
            try:
                tm = make()
            except AlignmentError as exc:
                errors.append(str(exc))
                continue
            if tm is not None:
                maps.append(tm)
        if maps:
            best = max(maps, key=lambda tm: segment_confidence(tm.confidence))
            out.append(SegmentMap(index, start, stop, best))
        else:
            out.append(SegmentMap(index, start, stop, None, f"not aligned: {errors[0]}"))
    return PiecewiseTimeMap(len(recorded), tuple(out), recorded.name)
