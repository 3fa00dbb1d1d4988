"""Per-segment temporal alignment joined into one piecewise time map, and the confidence threshold.

A recording cut into consistent segments (:mod:`milling_twin.orchestrator.recording_checks`, policy
``segment``) is simulated one segment at a time (``milling-twin reconstruct`` writes one program per
segment). :func:`align_segments` aligns each segment's recorded positions with the simulated run of its
program (:func:`milling_twin.orchestrator.align.align`) and joins the maps into a :class:`PiecewiseTimeMap`:
one row per recorded sample with its segment index and the simulated time on that segment's own clock
(it resets at each segment start, where the segment's run starts).

Per segment three candidate maps are made and the one the recording agrees with best is kept:

* ``multiscale`` (or the ``method`` asked for), which needs more samples than a ten-row segment has;
* ``offset``: simulated = recorded - offset, where ``offset`` is the recorded time at which the segment's program
  starts (``milling-twin reconstruct``'s segment programs reproduce the recorded timing from there);
* ``segment fit`` (:func:`fit_segment`): simulated = rate * (recorded - offset) + shift, the known structure of a
  segment program with the two numbers fitted to the segment's samples, to the millisecond: ``shift`` takes up
  the servo lag of the actual positions behind the commanded ones the program follows, ``rate`` a logger clock
  that runs a little fast or slow. The fit compares each stored position with the simulated one as storage
  does (a stored value is the true one rounded to its step, so only the distance beyond half a step counts)
  and, where the recorded axis velocities are given (finer than the positions), the velocities too, at the
  low weight FIT_VELOCITY_WEIGHT: a velocity sample is a snapshot, and where the machine stops for an instant
  between two blocks it reads ~0 while the program's constant feed between samples does not stop, so the
  velocities decide only where the positions leave the timing open (on the UMich runs a full weight
  misplaced 1-5 % of the cutting samples more).

Confidence of a sample (:func:`agreement`): how well the recording agrees with the simulation at the mapped
moment: 1 while the position residual is within 1.5 storage steps on every axis (:data:`TOLERANCE_STEPS`), falling
as 1/z^2 beyond (z = the residual in units of that tolerance); with recorded velocities, times (1 + c_v) / 2,
where c_v is the same measure of the velocity difference (tolerance 10 % of the speed plus 5 % of the
recording's top speed). A segment's confidence is the median of its samples' confidences. Below
``min_confidence`` (:data:`DEFAULT_MIN_CONFIDENCE` unless given) the alignment of that segment has failed:
``milling-twin align temporal`` lists such segments and calibration refuses pairs from them
(``[alignment].refuse_below`` of a spec, the same default; orchestrator/calibrate/pairing.py).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import pandas as pd

from milling_twin.orchestrator.align.errors import AlignmentError
from milling_twin.orchestrator.align.refine import confidence
from milling_twin.orchestrator.align.sampling import local_noise, storage_step
from milling_twin.orchestrator.align.temporal import align
from milling_twin.orchestrator.align.timemap import TimeMap
from milling_twin.orchestrator.align.trajectory import Trajectory

__all__ = ["DEFAULT_MIN_CONFIDENCE", "TOLERANCE_STEPS", "PiecewiseTimeMap", "SegmentMap", "agreement",
           "align_segments", "fit_segment", "segment_confidence"]

#: median confidence of a segment below which its alignment is taken as failed: with the confidence of
#: :func:`agreement`, fewer than half of the segment's samples within about 1.8 storage steps of the simulation
#: (or within 1.5 steps with velocities that disagree)
DEFAULT_MIN_CONFIDENCE = 0.3
#: a recorded position agrees with the simulated one within this many storage steps on every axis
TOLERANCE_STEPS = 1.5
#: velocity agreement: tolerance = VELOCITY_RELATIVE * speed + VELOCITY_FLOOR * the recording's top speed
VELOCITY_RELATIVE = 0.1
VELOCITY_FLOOR = 0.05
#: segment fit: the rate searched (the programs reproduce the recorded time within 1 %; the logger's clock may
#: run a little off), the shift searched (s, either side of the program's start; the servo lag is ~10 ms) and the
#: resolution the search ends at (s)
FIT_RATES = (0.9, 1.1)
FIT_SHIFT = 0.2
FIT_RESOLUTION = 5e-4
FIT_VELOCITY_WEIGHT = 0.1


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


def _tolerance(step: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Per sample and axis: TOLERANCE_STEPS storage steps, or 3 noise scales where positions are not stored
    rounded."""
    return np.where(step > 0, TOLERANCE_STEPS * step, 3.0 * sigma)


def _speed_scale(velocity: np.ndarray) -> float:
    """VELOCITY_FLOOR times the recording's top speed (99th percentile of the speed), at least 1e-12."""
    speed = np.linalg.norm(velocity, axis=1)
    return max(VELOCITY_FLOOR * float(np.percentile(speed, 99)) if speed.size else 0.0, 1e-12)


def agreement(residual: np.ndarray, tolerance: np.ndarray, velocity: np.ndarray | None = None,
              simulated_velocity: np.ndarray | None = None, floor: float = 0.0) -> np.ndarray:
    """Per-sample confidence (module text): ``residual`` and ``tolerance`` (n, 3) position residual and its
    tolerance per axis; ``velocity`` / ``simulated_velocity`` (n, 3) recorded and simulated velocities at the
    mapped moments (optional), ``floor`` the velocity tolerance's constant part. NaN residuals score 0."""
    z = np.max(np.abs(residual) / np.maximum(tolerance, 1e-300), axis=1)
    c = np.minimum(1.0, 1.0 / np.maximum(z, 1e-12) ** 2)
    if velocity is not None and simulated_velocity is not None:
        speed = np.maximum(np.linalg.norm(velocity, axis=1), np.linalg.norm(simulated_velocity, axis=1))
        e = np.linalg.norm(velocity - simulated_velocity, axis=1) / (VELOCITY_RELATIVE * speed + max(floor, 1e-300))
        c = c * 0.5 * (1.0 + np.minimum(1.0, 1.0 / np.maximum(e, 1e-12) ** 2))
    return np.clip(np.nan_to_num(c, nan=0.0), 0.0, 1.0)


def _velocity_at(sim: Trajectory, tau: np.ndarray) -> np.ndarray:
    v = sim.velocity()
    return np.stack([np.interp(tau, sim.time, v[:, a]) for a in range(3)], axis=-1)


def fit_segment(rec: Trajectory, sim: Trajectory, offset: float, step: np.ndarray, sigma: np.ndarray,
                velocity: np.ndarray | None = None, floor: float = 0.0) -> TimeMap:
    """The map simulated = rate * (recorded - offset) + shift that fits the segment best (module text): a grid
    over FIT_RATES and +-FIT_SHIFT, refined around the best point down to FIT_RESOLUTION. Cost per sample and
    axis: the distance of the simulated position beyond half the storage step from the stored one, in units of
    the tolerance (:func:`_tolerance`), capped at 3; with ``velocity``, plus the velocity difference over its
    tolerance (capped at 3). The map's confidence is :func:`agreement`."""
    half = 0.5 * step
    tol = _tolerance(step, sigma)
    sim_v = sim.velocity()
    dt = rec.time - offset

    def cost(rates: np.ndarray, shifts: np.ndarray) -> np.ndarray:
        out = np.zeros((rates.size, shifts.size))
        for k, rate in enumerate(rates):
            tau = rate * dt[None, :] + shifts[:, None]  # (shifts, n)
            for a in range(3):
                pos = np.interp(tau, sim.time, sim.position[:, a])
                excess = np.maximum(np.abs(pos - rec.position[:, a]) - half[:, a], 0.0) / tol[:, a]
                out[k] += np.sum(np.minimum(excess, 3.0) ** 2, axis=-1)
            if velocity is not None:
                sv = np.stack([np.interp(tau, sim.time, sim_v[:, a]) for a in range(3)], axis=-1)
                speed = np.maximum(np.linalg.norm(velocity, axis=1), np.linalg.norm(sv, axis=-1))
                e = np.linalg.norm(sv - velocity, axis=-1) / (VELOCITY_RELATIVE * speed + max(floor, 1e-300))
                out[k] += FIT_VELOCITY_WEIGHT * np.sum(np.minimum(e, 3.0) ** 2, axis=-1)
        return out

    lo, hi = FIT_RATES
    span = max(float(np.max(np.abs(dt))), FIT_RESOLUTION)
    rates = np.linspace(lo, hi, 21)
    shifts = np.arange(-FIT_SHIFT, FIT_SHIFT + 1e-12, 4 * FIT_RESOLUTION)
    dr, ds = rates[1] - rates[0], shifts[1] - shifts[0]
    rate, shift = 1.0, 0.0
    for _ in range(12):  # the grid, then finer grids around its best point
        c = cost(rates, shifts)
        k, m = np.unravel_index(int(np.argmin(c)), c.shape)
        rate, shift = float(rates[k]), float(shifts[m])
        if dr * span <= FIT_RESOLUTION and ds <= FIT_RESOLUTION:
            break
        dr, ds = dr / 4, max(ds / 4, FIT_RESOLUTION)
        rates = np.clip(rate + np.arange(-4, 5) * dr, lo, hi)
        shifts = shift + np.arange(-4, 5) * ds
    tau = np.clip(rate * dt + shift, sim.time[0], sim.time[-1])
    residual = rec.position - sim.at(tau)
    conf = agreement(residual, tol, velocity, _velocity_at(sim, tau) if velocity is not None else None, floor)
    return TimeMap(rec.time, tau, conf, "segment fit", {"offset": offset, "rate": rate, "shift": shift})


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
                   method: str = "multiscale", options: Any | None = None,
                   velocity: np.ndarray | None = None, step: np.ndarray | None = None) -> PiecewiseTimeMap:
    """Align each ``(index, start, stop, simulated[, offset])`` segment: the recorded rows ``start`` ..
    ``stop - 1`` against ``simulated`` (the run of that segment's program, its own clock; None: no program).
    ``offset``: the recorded time at which the segment's program starts, when it reproduces the recorded
    timing (``milling-twin reconstruct``'s segment programs); without it the segment's first sample.
    ``velocity``: the recorded axis velocities (n, 3; the positions' unit per second), used by the segment fit
    and the confidence; ``step``: the positions' storage steps (n, 3; default
    :func:`~milling_twin.orchestrator.align.sampling.storage_step` of the whole recording). Of the candidate maps
    (module text) the one of the highest mean confidence (:func:`agreement`) is kept; a simulated run without
    motion (a standing segment) maps every sample to its start. A segment that cannot be aligned gets no map and
    the reason (its confidence is 0)."""
    if velocity is not None:
        velocity = np.asarray(velocity, dtype=float)
        if velocity.shape != recorded.position.shape:
            raise AlignmentError(f"{recorded.name}: velocity must have the positions' shape "
                                 f"{recorded.position.shape}, got {velocity.shape}")
    step = storage_step(recorded.position) if step is None else np.asarray(step, dtype=float)
    sigma = local_noise(recorded.position, step)
    floor = _speed_scale(velocity) if velocity is not None else 0.0
    out = []
    for index, start, stop, simulated, *rest in segments:
        offset = rest[0] if rest and rest[0] is not None else None
        if simulated is None:
            out.append(SegmentMap(index, start, stop, None, "no simulated run (no program)"))
            continue
        if stop - start < 2:
            out.append(SegmentMap(index, start, stop, None, "fewer than 2 rows"))
            continue
        rows = slice(start, stop)
        rec = Trajectory(recorded.time[rows], recorded.position[rows], f"{recorded.name} segment {index}")
        vel = velocity[rows] if velocity is not None else None
        tol = _tolerance(step[rows], sigma[rows])

        def scored(tm: TimeMap) -> TimeMap:
            residual = rec.position - tm.resample_simulated(simulated.time, simulated.position)
            sim_v = _velocity_at(simulated, tm.simulated_time) if vel is not None else None
            return replace(tm, confidence=agreement(residual, tol, vel, sim_v, floor))

        if np.ptp(simulated.position, axis=0).max() <= 1e-12:
            flat = TimeMap(rec.time, np.full(len(rec), simulated.time[0]), np.ones(len(rec)), "standing")
            out.append(SegmentMap(index, start, stop, scored(flat)))
            continue
        t0 = offset if offset is not None else float(rec.time[0])
        maps, errors = [], []
        for make in (lambda: scored(align(rec, simulated, method, options)),
                     lambda: scored(_from_offset(rec, simulated, offset)) if offset is not None else None,
                     lambda: fit_segment(rec, simulated, t0, step[rows], sigma[rows], vel, floor)):
            try:
                tm = make()
            except AlignmentError as exc:
                errors.append(str(exc))
                continue
            if tm is not None:
                maps.append(tm)
        if maps:
            best = max(maps, key=lambda tm: float(np.mean(tm.confidence)))
            out.append(SegmentMap(index, start, stop, best))
        else:
            out.append(SegmentMap(index, start, stop, None, f"not aligned: {errors[0]}"))
    return PiecewiseTimeMap(len(recorded), tuple(out), recorded.name)
