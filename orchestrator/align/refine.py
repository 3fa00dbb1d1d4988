"""Sub-sample refinement of a time map, pauses, stationary stretches, monotonicity, confidence.

Given a map accurate to about a sample (the last DTW level), recorded positions ``p_i`` and the
simulated path ``s(tau)``:

1. **Base.** The DTW map is jagged by up to a sample; it is smoothed (moving average over
   ``base_smoothing`` s) within pieces between gaps, held runs and stationary samples.
2. **Quantization-aware local search.** For shifts ``d`` on a grid of ``2 * candidates + 1``
   points within +-``reach`` recorded sample periods, the cost of sample i is
   ``sum_a ((p_a - Q_a(s_a(tau_i + d))) / sigma_a)^2`` (capped at ``3 * robust^2``), where
   ``Q_a`` rounds to the axis' storage step at that sample
   (:func:`milling_twin.orchestrator.align.sampling.storage_step`: the UMich data keeps 3 significant
   digits, i.e. 1 mm steps above 100 mm and 0.1 mm below) and ``sigma_a`` is the local noise
   (step / sqrt(12), at least the white noise). Compared this way, a stored staircase matches
   the simulated ramp exactly when the timing is right, so the instants at which a stored
   value changes pin the time down to a fraction of a sample. The cost is averaged over
   ``smoothing`` seconds; the best shift is the centre of a flat minimum, else parabolic.
   ``s(tau + d)`` is the second-order Taylor expansion at ``tau``.
3. **Pauses.** A run of recorded positions that stay within one storage step for ``hold``
   seconds or more (:func:`held_runs`) between two moving samples, while the simulation moves
   by more than 1.5 steps between their times and does not itself stay at that position for
   half as long, is a pause of the machine: the whole run gets the one simulated time between
   the two that best matches the held position (dithered axes by their mean).
4. **Stationary stretches.** Where positions cannot tell time -- the simulation stands still
   at the mapped time (speed below ``stationary`` times its median moving speed: dwell,
   spindle start, before the first move), or a held run is not a pause (the simulation dwells
   too, or barely moves) -- the time is interpolated linearly between the nearest samples on
   either side that can tell it; beyond the first/last of those the global rate is
   extrapolated (clipped to the simulated run).
5. **Monotonic**: isotonic regression (``scipy.optimize.isotonic_regression``).
6. **Confidence** of sample i = ``c_res * c_id`` (halved inside held runs): ``c_res = 1``
   while the residual is within ``robust`` noise sigmas (RMS over the axes), ``(robust / z)^2``
   beyond; ``c_id = k^2 / (1 + k^2)`` where ``k`` is how many noise sigmas the simulation moves
   in one recorded sample period at the mapped time (0 where it stands still: the time there is
   only interpolated).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.ndimage import uniform_filter1d
from scipy.optimize import isotonic_regression

from milling_twin.orchestrator.align.errors import AlignmentError
from milling_twin.orchestrator.align.sampling import local_noise, storage_step
from milling_twin.orchestrator.align.trajectory import Trajectory

__all__ = ["RefineOptions", "confidence", "fill_stationary", "refine"]


@dataclass(frozen=True)
class RefineOptions:
    """See the module text: ``smoothing`` (s) cost window of the local search, ``reach``
    (recorded sample periods) and ``candidates`` (per side) its shifts; ``base_smoothing`` (s);
    ``stationary``: fraction of the median moving speed below which the simulation stands
    still; ``robust``: cost cap and confidence threshold in noise sigmas; ``hold``: seconds a
    held run lasts at least."""

    smoothing: float = 0.3
    stationary: float = 0.05
    robust: float = 3.0
    hold: float = 1.0
    reach: float = 1.0
    candidates: int = 10
    base_smoothing: float = 0.5


def _at(sim_time: np.ndarray, values: np.ndarray, tau: np.ndarray) -> np.ndarray:
    out = np.empty((tau.size, 3))
    for a in range(3):
        out[:, a] = np.interp(tau, sim_time, np.ascontiguousarray(values[:, a]))
    return out


def held_runs(time: np.ndarray, position: np.ndarray, min_duration: float,
              tolerance: np.ndarray | None = None) -> list[tuple[int, int]]:
    """Runs ``(first, end)`` (end exclusive) of at least ``min_duration`` seconds in which the
    position stays within ``tolerance`` (per sample and axis, (n, 3), taken at the run's first
    sample; default 0: identical values) over the whole run. With the storage step as
    tolerance, noise that flips the last stored digit back and forth does not break a run,
    while a machine creeping by one step after another does. Candidates come from windows of
    ``min_duration`` (max - min filters), which are then split where the run's range grows
    beyond the tolerance."""
    from scipy.ndimage import maximum_filter1d, minimum_filter1d

    n = time.size
    dt = float(np.median(np.diff(time)))
    w = max(2, int(np.ceil(min_duration / dt)))
    if n < w:
        return []
    tol = np.zeros((n, 3)) if tolerance is None else np.asarray(tolerance, dtype=np.float64)
    tol = tol + 1e-9 * (1.0 + np.abs(position))
    # window [i, i + w): range of each axis (origin shifts the filters to start at i)
    ok = np.ones(n, dtype=bool)
    org = -(w // 2)
    for a in range(3):
        hi = maximum_filter1d(position[:, a], w, mode="nearest", origin=org)
        lo = minimum_filter1d(position[:, a], w, mode="nearest", origin=org)
        ok &= hi - lo <= tol[:, a]
    ok[n - w + 1:] = False
    # a window starting at i covers i .. i + w - 1
    count = np.zeros(n + 1, dtype=np.int64)
    np.add.at(count, np.flatnonzero(ok), 1)
    np.add.at(count, np.flatnonzero(ok) + w, -1)
    held = np.cumsum(count[:-1]) > 0
    edges = np.flatnonzero(np.diff(np.concatenate([[0], held.astype(np.int8), [0]])))
    runs = []
    for a, b in zip(edges[::2], edges[1::2]):  # split where the whole run leaves tolerance
        runs.extend(_split_run(time, position, tol, int(a), int(b), min_duration))
    return runs


def _split_run(time: np.ndarray, position: np.ndarray, tol: np.ndarray, a: int, b: int,
               min_duration: float) -> list[tuple[int, int]]:
    """Maximal pieces of ``[a, b)`` whose total range per axis stays within ``tol`` (visiting
    only the samples where a value changes), kept if they last ``min_duration``."""
    changes = a + 1 + np.flatnonzero(np.any(np.diff(position[a:b], axis=0) != 0, axis=1))
    out, start = [], a
    lo = hi = position[a].copy()
    for k in changes:
        p = position[k]
        lo2, hi2 = np.minimum(lo, p), np.maximum(hi, p)
        if np.any(hi2 - lo2 > tol[start]):
            out.append((start, int(k)))
            start, lo, hi = int(k), p.copy(), p.copy()
        else:
            lo, hi = lo2, hi2
    out.append((start, b))
    end_time = lambda e: time[min(e, time.size - 1)]  # noqa: E731
    return [(s, e) for s, e in out if e - s >= 2 and end_time(e) - time[s] >= min_duration]


def place_pauses(rec: Trajectory, sim: Trajectory, tau: np.ndarray,
                 runs: list[tuple[int, int]], step: np.ndarray, sigma: np.ndarray,
                 resolution: float, rate: float) -> tuple[np.ndarray, np.ndarray]:
    """For each held run between two moving samples: if the simulation moves by more than 1.5
    storage steps between their times while the machine holds, and stays within a step of the
    held position for less than half as long as the machine (``rate``: simulated per recorded
    seconds), the machine paused: the whole run gets the one simulated time in between that
    best matches the held position (the centre of the best-matching stretch). Returns the new
    ``tau`` and a mask of the samples still to be interpolated (runs that are not pauses, and
    runs at either end)."""
    tau = tau.copy()
    fill = np.zeros(tau.size, dtype=bool)
    for a, b in runs:
        if a == 0 or b >= tau.size:
            fill[a:b] = True
            continue
        lo, hi = tau[a - 1], tau[b]
        cand = np.linspace(lo, hi, max(3, int(np.ceil((hi - lo) / resolution)) + 1))
        s = sim.at(cand)
        run = rec.position[a:b]
        # an axis whose stored value flips between two steps (noise near a rounding edge) is
        # dithered: its mean is finer than the step; a constant stored axis is compared with
        # the simulated value stored the same way
        constant = (np.ptp(run, axis=0) == 0) & (step[a] > 0)
        q = np.where(constant, step[a], 1.0)
        s = np.where(constant, np.round(s / q) * q, s)
        scale = np.where(constant, sigma[a], sigma[a] / np.sqrt(b - a))
        dev = np.sqrt(np.sum(((s - run.mean(axis=0)) / scale) ** 2, axis=1))
        best = dev <= dev.min() + 1e-9 * (1.0 + dev.min())
        raw = sim.at(cand)
        near = np.all(np.abs(raw - run.mean(axis=0)) <= np.maximum(step[a], 3 * sigma[a]), axis=1)
        stay = near.mean() * (hi - lo)  # how long the simulation stays at the held position
        moves = np.ptp(raw / sigma[a], axis=0).max() > 1.5 * np.sqrt(12)
        if not moves or stay >= 0.5 * (rec.time[b] - rec.time[a]) * rate:
            fill[a:b] = True  # the simulation holds there too (a dwell), or hardly moves
            continue
        tau[a:b] = float(np.mean(cand[best]))
    return tau, fill


def fill_stationary(rec_time: np.ndarray, tau: np.ndarray, standing: np.ndarray, rate: float,
                    t_lo: float, t_hi: float) -> np.ndarray:
    """``tau`` with the ``standing`` samples replaced as described in the module text."""
    good = ~standing
    if not good.any():
        raise AlignmentError("the simulation stands still at every mapped time: positions "
                             "cannot tell time (is the simulated path empty or constant?)")
    if good.all():
        return tau
    t_good, tau_good = rec_time[good], tau[good]
    out = np.interp(rec_time, t_good, tau_good)
    before, after = rec_time < t_good[0], rec_time > t_good[-1]
    out[before] = tau_good[0] - rate * (t_good[0] - rec_time[before])
    out[after] = tau_good[-1] + rate * (rec_time[after] - t_good[-1])
    return np.clip(np.where(standing, out, tau), t_lo, t_hi)


def confidence(res: np.ndarray, vel: np.ndarray, sigma: np.ndarray, sample_period: float,
               robust: float = 3.0) -> np.ndarray:
    z = np.sqrt(np.sum((res / sigma) ** 2, axis=1) / 3.0)
    c_res = np.minimum(1.0, (robust / np.maximum(z, robust * 1e-150)) ** 2)
    k = np.sqrt(np.sum((vel / sigma) ** 2, axis=1)) * sample_period
    return np.clip(c_res * k * k / (1.0 + k * k), 0.0, 1.0)


def local_search(rec: Trajectory, sim: Trajectory, tau: np.ndarray, held: np.ndarray,
                 sigma: np.ndarray, step: np.ndarray, offsets: np.ndarray, width: int,
                 robust: float, vel_sim: np.ndarray, acc_sim: np.ndarray) -> np.ndarray:
    """Best shift of each sample among ``offsets`` (simulated seconds) by the windowed cost
    (module text, step 1); the centre of a flat minimum, parabolic between grid points. The
    simulated position at ``tau + d`` is its second-order Taylor expansion at ``tau`` (the
    offsets are within a sample period or two), so each candidate costs arithmetic only."""
    n = tau.size
    cost = np.empty((offsets.size, n), dtype=np.float32)
    cap = np.float32(3.0 * robust ** 2)
    use = (~held).astype(np.float32)
    q = np.where(step > 0, step, 1.0)
    s0 = (_at(sim.time, sim.position, tau) / q).astype(np.float32)
    v0 = (_at(sim.time, vel_sim, tau) / q).astype(np.float32)
    a0 = (0.5 * _at(sim.time, acc_sim, tau) / q).astype(np.float32)
    r0 = (rec.position / q).astype(np.float32)
    wq = (q / sigma).astype(np.float32)
    quantized = [bool(np.any(step[:, a] > 0)) for a in range(3)]
    for k, d in enumerate(offsets):
        d32 = np.float32(d)
        c = np.zeros(n, dtype=np.float32)
        for a in range(3):
            s = s0[:, a] + d32 * (v0[:, a] + d32 * a0[:, a])
            if quantized[a]:  # steps are 1 where not quantized: rounding would be wrong there
                s = np.where(step[:, a] > 0, np.round(s), s)
            c += ((r0[:, a] - s) * wq[:, a]) ** 2
        cost[k] = uniform_filter1d(np.minimum(c, cap) * use, width, mode="nearest")
    best = cost.min(axis=0)
    flat = cost <= best + 1e-6 * (1.0 + best)
    count = flat.sum(axis=0)
    centre = (offsets[:, None] * flat).sum(axis=0) / count
    k = np.argmin(cost, axis=0)
    inner = (count == 1) & (k > 0) & (k < offsets.size - 1)
    kk = np.clip(k, 1, offsets.size - 2)
    idx = np.arange(n)
    c0, c1, c2 = (cost[kk - 1, idx].astype(np.float64), cost[kk, idx].astype(np.float64),
                  cost[kk + 1, idx].astype(np.float64))
    curv = c0 - 2 * c1 + c2
    frac = np.divide(0.5 * (c0 - c2), curv, out=np.zeros(n, dtype=np.float64),
                     where=curv > 0)
    parab = offsets[kk] + np.clip(frac, -0.5, 0.5) * (offsets[1] - offsets[0])
    return tau + np.where(inner, parab, centre)


def smooth_pieces(time: np.ndarray, tau: np.ndarray, use: np.ndarray, width: int) -> np.ndarray:
    """Moving average of ``tau`` over ``width`` samples using only the samples marked ``use``
    (the others keep their value), within pieces split at gaps of more than two median sample
    periods and at samples not used (kinks of the map are there)."""
    dt = np.diff(time)
    cut = np.flatnonzero((dt > 2.0 * np.median(dt)) | ~use[1:] | ~use[:-1]) + 1
    out = tau.copy()
    for a, b in zip(np.concatenate([[0], cut]), np.concatenate([cut, [tau.size]])):
        if b - a > 2 and use[a]:
            out[a:b] = uniform_filter1d(tau[a:b], min(width | 1, (b - a) | 1), mode="nearest")
    return out


def refine(rec: Trajectory, sim: Trajectory, tau: np.ndarray, rate: float, noise: np.ndarray,
           options: RefineOptions = RefineOptions()) -> tuple[np.ndarray, np.ndarray,
                                                              dict[str, Any]]:
    """Refined ``tau`` (one per recorded sample), its confidence and details (module text)."""
    t_lo, t_hi = float(sim.time[0]), float(sim.time[-1])
    vel_sim = np.asfortranarray(sim.velocity())  # contiguous columns for np.interp
    speed_sim = np.linalg.norm(vel_sim, axis=1)
    moving_speeds = speed_sim[speed_sim > 1e-6 * speed_sim.max()]
    speed_ref = float(np.median(moving_speeds)) if moving_speeds.size else 0.0
    if speed_ref <= 0:
        raise AlignmentError(f"{sim.name}: the simulated path never moves")
    dt = float(np.median(np.diff(rec.time)))
    period = dt * rate  # one recorded sample period in simulated seconds
    width = max(1, int(round(options.smoothing / dt)))
    tau = np.clip(np.asarray(tau, dtype=np.float64), t_lo, t_hi)
    step = storage_step(rec.position)
    runs = held_runs(rec.time, rec.position, options.hold, step)
    held = np.zeros(len(rec), dtype=bool)
    for a, b in runs:
        held[a:b] = True
    if options.base_smoothing > 0:  # DTW maps are jagged by up to a sample: smooth first
        moving = np.linalg.norm(_at(sim.time, vel_sim, tau), axis=1) >= (options.stationary
                                                                          * speed_ref)
        tau = smooth_pieces(rec.time, tau, moving & ~held,
                            max(1, int(round(options.base_smoothing / dt))))
    sigma = local_noise(rec.position, step)
    acc_sim = np.asfortranarray(np.gradient(vel_sim, sim.time, axis=0))
    grid = np.linspace(-1.0, 1.0, 2 * options.candidates + 1)
    tau = local_search(rec, sim, tau, held, sigma, step, grid * options.reach * period, width,
                       options.robust, vel_sim, acc_sim)
    tau = np.clip(tau, t_lo, t_hi)
    vel = _at(sim.time, vel_sim, tau)
    tau, fill = place_pauses(rec, sim, tau, runs, step, sigma, 0.1 * period, rate)
    standing = (np.linalg.norm(vel, axis=1) < options.stationary * speed_ref) & ~held | fill
    tau = fill_stationary(rec.time, tau, standing, rate, t_lo, t_hi)
    tau = np.clip(isotonic_regression(tau).x, t_lo, t_hi)
    tau = np.maximum.accumulate(tau)  # exact monotonicity after round-off
    vel = _at(sim.time, vel_sim, tau)
    res = rec.position - _at(sim.time, sim.position, tau)
    conf = confidence(res, vel, sigma, period, options.robust)
    conf[held] *= 0.5  # a held sample's time is that of the whole run
    return tau, conf, {"noise_sigma": np.median(sigma, axis=0).tolist(),
                       "standing_fraction": float(standing.mean()),
                       "held_fraction": float(held.mean())}
