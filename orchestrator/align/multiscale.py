"""The multiscale method: global rate from FFT cross-correlation over a scale pyramid, open-end
DTW on a coarse grid, banded DTW from coarse to fine around the previous level's map (all DTW in
dtaidistance's C code), then sub-sample refinement (:mod:`milling_twin.orchestrator.align.refine`).

1. **Global rate** ``a`` (simulated seconds per recorded second) and offset: the recorded
   positions on a coarse uniform grid are cross-correlated (FFT, all three axes, normalised)
   with the simulated positions resampled at step ``a * h`` for log-spaced ``a`` in
   ``rate_range``: ``scan_scales`` rates at ``scan_samples`` points, then nine rates around
   each of the three best at ``coarse_samples`` points. It sets the step of the coarse
   simulated grid and the rate used to extrapolate where positions cannot tell time.
2. **Coarse level, unbanded, open ends.** The recorded positions on ``coarse_samples`` uniform
   points (moving average over one step) against the *whole* simulated path at step ``a * h``,
   with free start and end on the simulated side (psi relaxation): the recording may start
   before or after the program and end before or after it, and the map may deviate from the
   affine one by any amount (feed overrides, pauses). Cost ``coarse_samples * M`` cells
   (``max_cells`` guards memory).
3. **Finer levels, banded.** Grids grow by ``level_factor`` up to the recorded samples
   themselves. At each level the recorded positions (moving average over one step) are paired
   with the simulated positions *at the times the previous level maps them to*; the true map
   is then near the diagonal, so a band of ``band`` previous-level steps (+2) suffices. The
   mean matched index of each recorded sample updates its simulated time. Uniform grids up to
   the last level keep gaps in the recording from leaving holes in the simulated sequence.
   The last level weighs each axis by its local noise (storage step), the others by its median.
   Cost O(N * band).
4. **Refinement** to a fraction of a sample, held positions (pauses), stationary stretches,
   monotonicity and confidence: :func:`milling_twin.orchestrator.align.refine.refine`.
"""
from __future__ import annotations

import math
import time as _time
from dataclasses import asdict, dataclass, field

import numpy as np
from dtaidistance import dtw_ndim
from scipy.signal import correlate
from tqdm import tqdm

from milling_twin.orchestrator.align.errors import AlignmentError
from milling_twin.orchestrator.align.refine import RefineOptions, refine
from milling_twin.orchestrator.align.sampling import decimate, local_noise, mean_match, sample, uniform_grid
from milling_twin.orchestrator.align.timemap import TimeMap
from milling_twin.orchestrator.align.trajectory import Trajectory

__all__ = ["MultiscaleOptions", "align_multiscale", "global_affine"]


@dataclass(frozen=True)
class MultiscaleOptions:
    """``rate_range``: allowed global rate (simulated s per recorded s); ``scan_samples``,
    ``scan_scales``: first rate scan; ``coarse_samples``: grid of the finer scan and of the
    coarse DTW level; ``max_cells``: largest coarse DTW matrix (8 bytes a cell);
    ``level_factor``: grid ratio between levels; ``band``: half-width of the finer levels'
    band in previous-level steps; ``penalty``: DTW cost of a non-diagonal step (noise units);
    ``refine``: sub-sample refinement; ``progress``: tqdm bar over the levels."""

    rate_range: tuple[float, float] = (0.6, 1.7)
    scan_samples: int = 512
    scan_scales: int = 48
    coarse_samples: int = 2048
    max_cells: float = 6e7
    level_factor: int = 6
    band: float = 2.0
    penalty: float = 1.0
    refine: RefineOptions = field(default_factory=RefineOptions)
    progress: bool = False

    def check(self) -> None:
        lo, hi = self.rate_range
        if not (0 < lo < hi and math.isfinite(hi)):
            raise AlignmentError(f"MultiscaleOptions.rate_range must be 0 < lo < hi, got "
                                 f"{self.rate_range}")
        for key in ("scan_samples", "scan_scales", "coarse_samples", "level_factor"):
            if int(getattr(self, key)) < 2:
                raise AlignmentError(f"MultiscaleOptions.{key} must be >= 2, got "
                                     f"{getattr(self, key)}")
        if not self.band > 0 or not self.penalty >= 0 or not self.max_cells > 0:
            raise AlignmentError("MultiscaleOptions: band and max_cells must be > 0, "
                                 "penalty >= 0")


def _scan(rec: Trajectory, sim: Trajectory, n: int, rates: np.ndarray, centre: np.ndarray,
          weight: float) -> list[tuple[float, float, float]]:
    """(score, rate, b) of the best lag for each rate, recorded on an n-point grid."""
    grid = uniform_grid(rec.time[0], rec.time[-1], n)
    h = grid[1] - grid[0]
    r = (sample(rec, grid, h) - centre) * weight
    r_norm = float(np.sqrt(np.sum(r * r))) or 1.0
    out = []
    for a in rates:
        m = int(sim.duration / (a * h)) + 1
        if m < 2:
            continue
        taus = sim.time[0] + a * h * np.arange(m)
        s = (sample(sim, taus, a * h) - centre) * weight
        c = sum(correlate(r[:, k], s[:, k], mode="full", method="fft") for k in range(3))
        c /= r_norm * (float(np.sqrt(np.sum(s * s))) or 1.0)
        best = int(np.argmax(c))
        lag = best - (m - 1)  # r[i + lag] ~ s[i]: recorded grid point i maps to taus[i - lag]
        out.append((float(c[best]), float(a), float(sim.time[0] - lag * a * h)))
    return out


def global_affine(rec: Trajectory, sim: Trajectory,
                  options: MultiscaleOptions = MultiscaleOptions()) -> tuple[float, float, float]:
    """(a, b, score) of the best global map ``tau = b + a * (t - rec.time[0])`` (step 1)."""
    options.check()
    centre = sim.position.mean(axis=0)
    weight = 1.0 / max(float(np.ptp(sim.position, axis=0).max()), 1e-300)
    lo, hi = options.rate_range
    rates = np.geomspace(lo, hi, options.scan_scales)
    n_rec = 4 * options.coarse_samples  # the scans need nothing finer: decimate once
    rec = decimate(rec, n_rec)
    sim = decimate(sim, int(n_rec * max(1.0, sim.duration / max(rec.duration, 1e-300)) / lo))
    first = _scan(rec, sim, min(options.scan_samples, len(rec)), rates, centre, weight)
    if not first:
        raise AlignmentError(f"{sim.name}: too short to scan the rates {options.rate_range}")
    first.sort(reverse=True)
    step = (hi / lo) ** (1.0 / max(options.scan_scales - 1, 1))
    fine = np.unique(np.concatenate([np.geomspace(a / step, a * step, 9) for _, a, _ in first[:3]]))
    score, a, b = max(_scan(rec, sim, min(options.coarse_samples, len(rec)), fine, centre, weight))
    return a, b, score


def _path_map(a_seq: np.ndarray, b_seq: np.ndarray, b_times: np.ndarray, penalty: float,
              window: int | None = None, psi: int | None = None) -> np.ndarray:
    """DTW of two sequences: simulated time (from ``b_times``) of each element of ``a_seq``."""
    n = a_seq.shape[0]
    path = dtw_ndim.warping_path(np.ascontiguousarray(a_seq), np.ascontiguousarray(b_seq),
                                 window=window, penalty=penalty,
                                 psi=None if psi is None else (0, 0, psi, psi), use_c=True)
    if len(path) < n:  # guard against degenerate paths of the C code
        raise AlignmentError(f"DTW of {n} x {b_seq.shape[0]} samples (window {window}, psi "
                             f"{psi}) returned a path of {len(path)} cells")
    return np.interp(mean_match(path, n), np.arange(b_times.size), b_times)


def coarse_level(rec: Trajectory, sim: Trajectory, size: int, rate: float, weight: np.ndarray,
                 options: MultiscaleOptions) -> tuple[np.ndarray, np.ndarray]:
    """Step 2: (grid times, simulated time of each) from unbanded open-end DTW."""
    times = uniform_grid(rec.time[0], rec.time[-1], size)
    h = times[1] - times[0]
    # step a*h, but at least as many points as the recorded grid: dtaidistance's psi
    # relaxation of the second sequence returns a one-cell path when it is the shorter one
    b_step = min(h * rate, sim.duration / size)
    b_times = np.arange(sim.time[0], sim.time[-1] + 0.5 * b_step, b_step)
    cells = float(size) * b_times.size
    if cells > options.max_cells:
        raise AlignmentError(
            f"{sim.name}: the coarse level would need {size} x {b_times.size} = {cells:.3g} DTW "
            f"cells ({8 * cells / 2**30:.1f} GiB), more than max_cells={options.max_cells:.3g}: "
            f"is the simulated run ({sim.duration:.0f} s) much longer than the recording "
            f"({rec.duration:.0f} s)? Cut it to the part recorded, or lower coarse_samples")
    a_seq = sample(rec, times, h) * weight
    b_seq = sample(sim, b_times, b_step) * weight
    return times, _path_map(a_seq, b_seq, b_times, options.penalty, psi=b_times.size - 1)


def fine_level(rec: Trajectory, sim: Trajectory, times: np.ndarray, guess: np.ndarray,
               rate: float, window: int, weight: np.ndarray, penalty: float,
               final: bool) -> np.ndarray:
    """Step 3: simulated time of each of ``times`` by banded DTW around ``guess``."""
    h = (times[-1] - times[0]) / max(times.size - 1, 1)
    if final:  # per-sample noise weights once the band is narrow
        a_seq = rec.position * weight
        b_seq = sample(sim, guess, h * rate) * weight
    else:
        w = np.median(weight, axis=0)
        a_seq = sample(rec, times, h) * w
        b_seq = sample(sim, guess, h * rate) * w
    return _path_map(a_seq, b_seq, guess, penalty, window=window)


def align_multiscale(recorded: Trajectory, simulated: Trajectory,
                     options: MultiscaleOptions = MultiscaleOptions()) -> TimeMap:
    """Map every recorded sample to its simulated time (see the module text)."""
    options.check()
    start = _time.perf_counter()
    rec, sim = recorded, simulated
    n = len(rec)
    a, b, score = global_affine(rec, sim, options)
    noise = local_noise(rec.position)
    weight = 1.0 / noise
    sizes = [min(n, options.coarse_samples)]
    while sizes[-1] * options.level_factor < n:
        sizes.append(sizes[-1] * options.level_factor)
    sizes.append(n)  # the last level always has the recorded samples and a narrow band
    t_lo, t_hi = sim.time[0], sim.time[-1]
    levels = []
    bar = tqdm(total=len(sizes), desc="align levels", disable=not options.progress, leave=False)
    grid, tau = coarse_level(rec, sim, sizes[0], a, np.median(weight, axis=0), options)
    levels.append({"samples": sizes[0], "window": None})
    bar.update()
    for level in range(1, len(sizes)):
        final = level == len(sizes) - 1
        times = rec.time if final else uniform_grid(rec.time[0], rec.time[-1], sizes[level])
        guess = np.clip(np.interp(times, grid, tau), t_lo, t_hi)
        window = int(math.ceil(options.band * sizes[level] / sizes[level - 1])) + 2
        tau = np.clip(fine_level(rec, sim, times, guess, a, window, weight, options.penalty,
                                 final), t_lo, t_hi)
        grid = times
        levels.append({"samples": sizes[level], "window": window})
        bar.update()
    bar.close()
    tau, confidence, details = refine(rec, sim, tau, a, noise, options.refine)
    info = {"rate": a, "offset": b, "affine_score": score, "levels": levels,
            "options": asdict(options), "wall_time": _time.perf_counter() - start, **details}
    return TimeMap(rec.time, tau, confidence, "multiscale", info)
