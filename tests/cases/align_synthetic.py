"""Known warps of a simulated path: recorded-like data with ground truth, for tests and benchmarks.

:func:`path_from_umich` turns a real UMich recording (10 Hz, positions in 1 mm / 0.1 mm steps)
into a smooth "simulated" path: positions smoothed (Gaussian, 0.2 s) and interpolated by cubic
splines to the requested rate. :func:`make_recording` plays such a path through a
:class:`Warp` (the machine's timing) and degrades it like the real data: Gaussian noise,
quantization to 3 significant digits (the data's 1 mm steps above 100 mm, 0.1 mm below),
dropouts. The true simulated time of every recorded sample is returned with it.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.interpolate import PchipInterpolator
from scipy.ndimage import gaussian_filter1d

from milling_twin.orchestrator.align.errors import AlignmentError
from milling_twin.orchestrator.align.trajectory import Trajectory

__all__ = ["Recording", "Warp", "concatenate_paths", "make_recording", "path_from_umich",
           "quantize_significant", "random_warp", "umich_row_times"]

UMICH_COLUMNS = ("X1_ActualPosition", "Y1_ActualPosition", "Z1_ActualPosition")


UMICH_VELOCITIES = ("X1_ActualVelocity", "Y1_ActualVelocity", "Z1_ActualVelocity")


def umich_row_times(position: np.ndarray, velocity: np.ndarray, period: float = 0.1,
                    slack: float = 2.0, rapid: float = 50.0) -> np.ndarray:
    """Plausible times of the rows of a UMich recording. The rows are not evenly spaced in
    time: positions jump by up to ~200 mm between consecutive rows (often every 10th row) while
    the recorded velocities stay smooth, so the logger skipped time there. A step whose jump
    exceeds what the recorded speed allows in one ``period`` by more than ``slack`` mm takes
    ``jump / speed`` (the larger recorded speed of its two rows; where both are below 1 mm/s,
    the jump is taken as a rapid move at ``rapid`` mm/s); every other step takes ``period``."""
    jump = np.linalg.norm(np.diff(position, axis=0), axis=1)
    speed = np.linalg.norm(velocity, axis=1)
    speed = np.maximum(speed[:-1], speed[1:])
    speed = np.where(speed < 1.0, rapid, speed)
    step = np.where(jump > speed * period + slack, jump / speed, period)
    return np.concatenate([[0.0], np.cumsum(step)])


UMICH_DATA_ENV = "MILLING_TWIN_UMICH_DATA"


def umich_data_dir(option: str | Path | None = None) -> Path:
    """The folder of the full UMich recordings (experiment_NN.csv): ``option``, else $MILLING_TWIN_UMICH_DATA,
    else ../shared/data/umich_cnc beside the repository; an AlignmentError says where it looked."""
    repo = Path(__file__).resolve().parents[2]
    folder = Path(option or os.environ.get(UMICH_DATA_ENV) or repo.parent / "shared" / "data" / "umich_cnc")
    if not folder.is_dir():
        raise AlignmentError(f"UMich recordings not found in {folder}: pass --data DIR (experiment_NN.csv files) "
                             f"or set {UMICH_DATA_ENV}")
    return folder


def path_from_umich(csv_path: str | Path, rate: float = 100.0, smooth: float = 0.2,
                    retime: bool = True) -> Trajectory:
    """A smooth simulated path (mm, s from 0) from the positions of a UMich recording: rows
    re-timed by :func:`umich_row_times` (unless ``retime`` is false), interpolated (PCHIP, no
    overshoot) at ``rate`` samples per second and smoothed (Gaussian, sigma ``smooth`` s)."""
    frame = pd.read_csv(csv_path)
    missing = [c for c in (*UMICH_COLUMNS, *UMICH_VELOCITIES) if c not in frame.columns]
    if missing:
        raise AlignmentError(f"{csv_path}: no column {missing[0]!r}")
    pos = frame[list(UMICH_COLUMNS)].to_numpy(dtype=np.float64)
    vel = frame[list(UMICH_VELOCITIES)].to_numpy(dtype=np.float64)
    rows = umich_row_times(pos, vel) if retime else np.arange(pos.shape[0]) * 0.1
    t = np.arange(int(rows[-1] * rate) + 1) / rate
    pos = gaussian_filter1d(PchipInterpolator(rows, pos, axis=0)(t), smooth * rate, axis=0,
                            mode="nearest")
    return Trajectory(t, pos, f"{Path(csv_path).name} @ {rate:g} Hz")


def concatenate_paths(paths: list[Trajectory], duration: float, blend: float = 2.0,
                      shift: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> Trajectory:
    """One long path: ``paths`` in turn (cycling) until ``duration`` seconds, each joined to the
    next by a smooth (cosine) move of ``blend`` seconds; the k-th cycle through the list is
    moved by ``k * shift`` (several parts on one table). All paths share one sample rate."""
    dt = float(np.median(np.diff(paths[0].time)))
    nb = max(2, int(round(blend / dt)))
    ramp = (0.5 - 0.5 * np.cos(np.linspace(0.0, np.pi, nb)))[:, None]
    pieces, total, k = [], 0, 0
    last = None
    while total * dt < duration:
        pos = paths[k % len(paths)].position + (k // len(paths)) * np.asarray(shift)
        if last is not None:
            join = last + (pos[0] - last) * ramp
            pieces.append(join)
            total += nb
        pieces.append(pos)
        total += pos.shape[0]
        last = pos[-1]
        k += 1
    pos = np.concatenate(pieces)[: int(duration / dt) + 1]
    return Trajectory(np.arange(pos.shape[0]) * dt, pos, f"{len(paths)} paths cycled, {duration:g} s")


@dataclass(frozen=True)
class Warp:
    """How the machine's clock relates to the simulation's.

    ``start``: recorded time (s) at which the program starts (> 0: the recording starts idle
    before it; < 0: the recording misses the start). ``scale``: recorded duration per simulated
    duration (global). ``overrides``: (simulated time, speed factor) from which on the machine
    runs at that factor (feed override); ``pauses``: (simulated time, recorded seconds) where
    the machine stops. ``tail``: recorded seconds after the program end."""

    start: float = 0.0
    scale: float = 1.0
    overrides: tuple[tuple[float, float], ...] = ()
    pauses: tuple[tuple[float, float], ...] = ()
    tail: float = 0.0

    def recorded_clock(self, t_sim_end: float) -> tuple[np.ndarray, np.ndarray]:
        """Breakpoints (simulated times, recorded times) of the piecewise-linear clock."""
        knots = sorted({0.0, t_sim_end, *(s for s, _ in self.overrides if 0 < s < t_sim_end),
                        *(s for s, _ in self.pauses if 0 < s < t_sim_end)})
        factor = dict(sorted(self.overrides))
        pause = dict(self.pauses)
        tau, rec = [0.0], [self.start]
        current = 1.0
        for k0, k1 in zip(knots[:-1], knots[1:]):
            current = factor.get(k0, current)
            if k0 in pause:
                tau.append(k0)
                rec.append(rec[-1] + pause[k0])
            tau.append(k1)
            rec.append(rec[-1] + (k1 - k0) * self.scale / current)
        return np.array(tau), np.array(rec)

    def simulated_time(self, recorded_time: np.ndarray, t_sim_end: float) -> np.ndarray:
        tau, rec = self.recorded_clock(t_sim_end)
        return np.interp(recorded_time, rec, tau)  # clamps: idle before and after the program

    def duration(self, t_sim_end: float) -> float:
        return float(self.recorded_clock(t_sim_end)[1][-1] + self.tail)


def quantize_significant(values: np.ndarray, digits: int = 3) -> np.ndarray:
    """Round to ``digits`` significant digits, as the UMich data stores positions."""
    v = np.asarray(values, dtype=np.float64)
    mag = np.floor(np.log10(np.maximum(np.abs(v), 1e-300)))
    unit = 10.0 ** (mag - digits + 1)
    return np.round(v / unit) * unit


@dataclass(frozen=True)
class Recording:
    """A degraded recording and the true simulated time of each of its samples."""

    trajectory: Trajectory
    truth: np.ndarray
    warp: Warp
    info: dict[str, float] = field(default_factory=dict)


def make_recording(sim: Trajectory, warp: Warp, sample_period: float = 0.1,
                   noise: float = 0.01, quantize: bool = True, gaps: int = 0,
                   gap_length: tuple[float, float] = (0.5, 3.0), drop: float = 0.0,
                   rng: np.random.Generator | None = None) -> Recording:
    """Sample ``sim`` through ``warp`` every ``sample_period`` recorded seconds, add Gaussian
    ``noise`` (sim units), quantize, cut ``gaps`` blocks of ``gap_length`` seconds and drop a
    fraction ``drop`` of single samples."""
    rng = rng or np.random.default_rng(0)
    t_end = sim.time[-1]
    n = int(warp.duration(t_end) / sample_period) + 1
    t = np.arange(n) * sample_period
    keep = np.ones(n, dtype=bool)
    for _ in range(gaps):
        length = int(rng.uniform(*gap_length) / sample_period)
        first = int(rng.integers(1, max(2, n - length - 1)))
        keep[first:first + length] = False
    if drop > 0:
        keep &= rng.random(n) >= drop
    keep[[0, -1]] = True
    t = t[keep]
    truth = warp.simulated_time(t, t_end)
    pos = sim.at(truth) + rng.normal(0.0, noise, (t.size, 3)) if noise > 0 else sim.at(truth)
    if quantize:
        pos = quantize_significant(pos)
    return Recording(Trajectory(t, pos, f"recorded({sim.name})"), truth, warp,
                     {"samples": float(t.size), "kept": float(keep.mean())})


def random_warp(kind: str, t_sim_end: float, rng: np.random.Generator) -> Warp:
    """A warp of one benchmark kind: ``affine`` (offset and global scale 0.8..1.25),
    ``piecewise`` (+ 3..6 feed-override changes 0.6..1.5), ``pause`` (+ one pause of 5..30 s),
    ``all`` (overrides, two pauses, idle start and tail)."""
    start = float(rng.uniform(-3.0, 8.0))
    scale = float(np.exp(rng.uniform(np.log(0.8), np.log(1.25))))
    overrides: list[tuple[float, float]] = []
    pauses: list[tuple[float, float]] = []
    if kind in ("piecewise", "all"):
        for s in np.sort(rng.uniform(0.05, 0.95, int(rng.integers(3, 7)))) * t_sim_end:
            overrides.append((float(s), float(rng.uniform(0.6, 1.5))))
    if kind in ("pause", "all"):
        for s in rng.uniform(0.1, 0.9, 1 if kind == "pause" else 2) * t_sim_end:
            pauses.append((float(s), float(rng.uniform(5.0, 30.0))))
    if kind not in ("affine", "piecewise", "pause", "all"):
        raise AlignmentError(f"unknown warp kind {kind!r}: expected affine, piecewise, pause, all")
    tail = float(rng.uniform(0.0, 5.0)) if kind == "all" else 0.0
    return Warp(start, scale, tuple(overrides), tuple(pauses), tail)
