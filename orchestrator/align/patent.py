"""The registration method of the process-simulation patent, step by step.

1. Features: tool x, y, z over time, recorded (actual positions) and simulated (interpolator).
2. Each axis of each curve is min-max normalised to [0, 1] over its own motion envelope.
3. Each normalised axis on a uniform time grid (``sample_period``; default the recorded median
   period; seconds from program start) is the 1-D "feature image" of that axis.
4. The valid part of the recorded time axis (from the first to the last motion) is divided, for
   each of ``divisions`` counts drawn by a seeded generator from [``num1``, ``num2``], into that
   many equal parts: segments of different lengths for different counts.
5. The simulated curve is time-scaled into variants by factors ``beta`` of the arithmetic
   sequence ``beta_first + k * beta_step`` (k < ``beta_count``), in both directions given by
   the direction coefficient alpha: alpha = 1 stretches the simulated time by beta, alpha = 0
   compresses it by beta (factor ``beta ** (2 * alpha - 1)``); values are resampled by linear
   interpolation.
6. Each segment slides over each scaled curve one sample at a time from the left, keeping its
   size; the similarity at each offset is recorded, and a segment may only start where the
   previous segment of its division ended (later segments lie to the right). **Our similarity
   (the patent combines three normalised agreement counts around a zero split threshold,
   f1, f2, f3):** the slope of each curve over ``slope_lag`` samples is split at zero into
   rising (> +d), falling (< -d) and still (|slope| <= d, d = ``dead_band`` times the
   recorded axis' storage step in normalised units, so one stored step counts as motion);
   f1, f2, f3 are the numbers of samples where both curves rise, fall, stand still, each
   divided by the number of samples of that class in the recorded segment; the score is their
   mean over the classes that occur (1 = the same up/down/still pattern). All offsets are
   scored at once with FFT correlations of the class indicators (the same numbers as the
   sliding loop).
7. Voting: per axis, every segment votes for the scale variant where its best score is highest
   (a segment whose best score is reached by several variants, e.g. where the axis stands
   still, does not vote); the variant with most votes wins (ties: higher total score). For each axis' winner, the
   division with the best mean score gives the map; its mapped simulated curve (all three axes)
   is compared with the recorded curve by the sum of absolute differences divided by the length;
   the axis with the smallest wins.
8. Inverse transform: a recorded grid sample ``i`` of a segment starting at ``i0`` and matched
   at offset ``o`` of the variant with factor ``f`` corresponds to simulated time
   ``(o + i - i0) * h / f``; before the first and after the last segment the first/last
   segment's map continues (clipped to the run); recorded samples are mapped by linear
   interpolation on the grid. Confidence: the best score of the sample's segment.
"""
from __future__ import annotations

import time as _time
from dataclasses import asdict, dataclass

import numpy as np
from scipy.signal import correlate

from milling_twin.orchestrator.align.errors import AlignmentError
from milling_twin.orchestrator.align.sampling import axis_noise
from milling_twin.orchestrator.align.timemap import TimeMap
from milling_twin.orchestrator.align.trajectory import Trajectory

__all__ = ["PatentOptions", "align_patent", "slope_classes"]


@dataclass(frozen=True)
class PatentOptions:
    num1: int = 4
    num2: int = 12
    divisions: int = 3
    seed: int = 0
    beta_first: float = 1.0
    beta_step: float = 0.025
    beta_count: int = 13
    alphas: tuple[int, ...] = (0, 1)
    sample_period: float | None = None
    slope_lag: int = 3
    dead_band: float = 0.5

    def check(self) -> None:
        if not 1 <= self.num1 <= self.num2:
            raise AlignmentError(f"PatentOptions: need 1 <= num1 <= num2, got {self.num1}, "
                                 f"{self.num2}")
        if self.divisions < 1 or self.beta_count < 1 or self.slope_lag < 1:
            raise AlignmentError("PatentOptions: divisions, beta_count and slope_lag must be >= 1")
        if self.beta_first <= 0 or self.beta_step < 0:
            raise AlignmentError("PatentOptions: beta_first must be > 0 and beta_step >= 0")
        if not self.alphas or any(a not in (0, 1) for a in self.alphas):
            raise AlignmentError(f"PatentOptions.alphas must be a non-empty subset of (0, 1), "
                                 f"got {self.alphas}")


def _normalise(curve: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    lo, span = curve.min(axis=0), np.ptp(curve, axis=0)
    span = np.where(span > 0, span, 1.0)
    return (curve - lo) / span, span


def slope_classes(curve: np.ndarray, lag: int, dead_band: float) -> np.ndarray:
    """Class of the slope over ``lag`` samples: 0 still, 1 rising, 2 falling (length n - lag)."""
    slope = curve[lag:] - curve[:-lag]
    return np.where(slope > dead_band, 1, np.where(slope < -dead_band, 2, 0))


def _scores(seg_cls: np.ndarray, sim_cls: np.ndarray) -> np.ndarray:
    """Score of the segment at every offset of the simulated class sequence (module step 6)."""
    total = np.zeros(sim_cls.size - seg_cls.size + 1)
    present = 0
    for k in (0, 1, 2):
        r = (seg_cls == k).astype(np.float64)
        count = r.sum()
        if count == 0:
            continue
        present += 1
        total += correlate((sim_cls == k).astype(np.float64), r, mode="valid",
                           method="fft") / count
    return np.clip(total / max(present, 1), 0.0, 1.0)


def align_patent(recorded: Trajectory, simulated: Trajectory,
                 options: PatentOptions = PatentOptions()) -> TimeMap:
    options.check()
    start = _time.perf_counter()
    h = options.sample_period or float(np.median(np.diff(recorded.time)))
    grid = np.arange(recorded.time[0], recorded.time[-1] + 0.5 * h, h)
    rec, rec_span = _normalise(recorded.at(grid))
    sim_grid = np.arange(simulated.time[0], simulated.time[-1] + 0.5 * h, h)
    sim, _ = _normalise(simulated.at(sim_grid))
    dead = options.dead_band * axis_noise(recorded.position) * np.sqrt(12) / rec_span
    moved = np.any(np.abs(rec - rec[0]) > 1e-9, axis=1), np.any(np.abs(rec - rec[-1]) > 1e-9,
                                                               axis=1)
    if not moved[0].any():
        raise AlignmentError(f"{recorded.name}: the recorded positions never change")
    i0 = max(int(np.argmax(moved[0])) - 1, 0)
    i1 = int(len(grid) - np.argmax(moved[1][::-1]))  # one past the last motion
    valid = i1 - i0
    lag = options.slope_lag
    rng = np.random.default_rng(options.seed)
    counts = rng.integers(options.num1, options.num2 + 1, size=options.divisions)
    divisions = []
    for c in counts:
        edges = i0 + np.round(np.linspace(0, valid, int(c) + 1)).astype(int)
        segs = [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:]) if b - a > lag + 1]
        if not segs:
            raise AlignmentError(f"{recorded.name}: {valid} valid samples are too few for "
                                 f"{c} segments of more than {lag + 1} samples")
        divisions.append(segs)
    betas = options.beta_first + options.beta_step * np.arange(options.beta_count)
    factors = np.unique(np.concatenate([betas ** (2 * a - 1) for a in options.alphas]))
    rec_cls = [slope_classes(rec[:, a], lag, dead[a]) for a in range(3)]
    # result[axis][factor index][division index] = (offsets, scores)
    results: list[list[list[tuple[list[int], list[float]]]]] = []
    for axis in range(3):
        per_factor = []
        for f in factors:
            t_scaled = np.arange(int(sim_grid.size * f)) * h / f
            scaled = np.interp(t_scaled, sim_grid - sim_grid[0], sim[:, axis])
            sim_cls = slope_classes(scaled, lag, dead[axis])
            per_div = []
            for segs in divisions:
                lo, offsets, scores = 0, [], []
                for a, b in segs:
                    seg = rec_cls[axis][a:b - lag]
                    room = sim_cls.size - seg.size
                    if room < lo or room < 0:  # no place left to the right: worst score
                        o = max(min(lo, room), 0)
                        offsets.append(o)
                        scores.append(0.0)
                    else:
                        sc = _scores(seg, sim_cls)[lo:]
                        o = lo + int(np.argmax(sc))
                        offsets.append(o)
                        scores.append(float(sc[o - lo]))
                    lo = o + (b - a)
                per_div.append((offsets, scores))
            per_factor.append(per_div)
        results.append(per_factor)
    candidates = []
    for axis in range(3):
        score = np.array([[s for d in results[axis][k] for s in d[1]]
                          for k in range(factors.size)])  # factor x segment
        # a segment that fits several variants equally well (e.g. an axis standing still in
        # it) tells nothing: only segments with a single best variant vote
        top = score.max(axis=0)
        decisive = np.sum(score >= top - 1e-12, axis=0) == 1
        votes = np.bincount(np.argmax(score[:, decisive], axis=0), minlength=factors.size)
        best = votes.max()
        tied = np.flatnonzero(votes == best)
        k = int(tied[np.argmax(score[tied].sum(axis=1))])
        d = int(np.argmax([np.mean(results[axis][k][j][1]) for j in range(len(divisions))]))
        tau_grid, conf_grid = _inverse(divisions[d], results[axis][k][d], factors[k], h,
                                       grid.size, sim_grid)
        mapped = np.stack([np.interp(tau_grid, sim_grid, sim[:, a]) for a in range(3)], axis=1)
        sad = float(np.abs(mapped[i0:i1] - rec[i0:i1]).sum() / max(valid, 1))
        candidates.append((sad, axis, float(factors[k]), d, tau_grid, conf_grid, votes.tolist()))
    sad, axis, factor, d, tau_grid, conf_grid, votes = min(candidates, key=lambda c: c[0])
    tau = np.interp(recorded.time, grid, tau_grid)
    conf = np.interp(recorded.time, grid, conf_grid)
    return TimeMap(recorded.time, np.maximum.accumulate(tau), np.clip(conf, 0, 1), "patent",
                   {"axis": "xyz"[axis], "factor": factor, "division_counts": counts.tolist(),
                    "division": d, "sad": sad, "votes": votes, "options": asdict(options),
                    "wall_time": _time.perf_counter() - start})


def _inverse(segs: list[tuple[int, int]], matched: tuple[list[int], list[float]], factor: float,
             h: float, n: int, sim_grid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Simulated time and confidence of every recorded grid sample (module step 8)."""
    offsets, scores = matched
    idx = np.arange(n, dtype=np.float64)
    scaled = np.empty(n)
    conf = np.empty(n)
    for j, ((a, b), o, s) in enumerate(zip(segs, offsets, scores)):
        lo = 0 if j == 0 else a
        hi = n if j == len(segs) - 1 else b
        scaled[lo:hi] = o + idx[lo:hi] - a
        conf[lo:hi] = s
    tau = sim_grid[0] + np.clip(scaled * h / factor, 0.0, sim_grid[-1] - sim_grid[0])
    return tau, conf
