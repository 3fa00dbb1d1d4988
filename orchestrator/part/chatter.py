"""The chatter indicator of a block: how much of the tool's vibration is not forced by the tooth passing.

Stable milling vibrates at the tooth-passing frequency ``f_tp = n_flutes * spindle_speed / 2pi`` and its
harmonics (the force is periodic with the tooth period); regenerative chatter adds a vibration near a mode of
the tool that is not a harmonic and that grows until the flutes leave the cut. From the tip displacement
``(dx, dy)`` over a block's in-cut samples (evenly spaced, a contiguous run):

- the **indicator** (0..1): the displacement minus its mean, Hann-windowed; the energy of both axes'
  spectra ``|X(f)|^2 + |Y(f)|^2`` from ``f_tp / 2`` up to the Nyquist frequency (below it is the quasi-static
  deflection following the engagement, not vibration); the part of it outside the harmonic bands
  ``|f - k f_tp| <= max(HARMONIC_BAND * k * f_tp, 2 df)`` (k = 1, 2, ...; ``df`` the resolution of the
  spectrum, 2 df the half-width of the Hann window's main lobe, so a harmonic's own leakage stays inside its
  band) divided by the whole. Pure harmonics give 0; chatter near 1.
- the **growth rate** (1/s): the RMS of the resultant displacement (minus its mean) over successive whole
  tooth periods, and the least-squares slope of its natural log over the periods' mid times. Forced vibration
  repeats every tooth period (slope 0); the transient of an entry dies out (negative); chatter grows (positive
  until the flutes leave the cut and it saturates).

A block chatters when its indicator exceeds :data:`CHATTER_THRESHOLD` (docs/process_report.md says why) and its
vibration does not die out: a growth rate that shrinks it by a factor e or more over the analysed run (growth x
run length <= -:data:`DECAY_LIMIT`) is the free vibration after the flutes leave a cut or an entry's transient,
which has the mode's frequency (so a high indicator) but is no self-excited vibration.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

HARMONIC_BAND = 0.02      # relative half-width of the band around each tooth-passing harmonic
MIN_TOOTH_PERIODS = 4     # fewer in-cut tooth periods in a block: no indicator (NaN)
MIN_SAMPLES = 32          # fewer in-cut samples in a run: too short for a spectrum
CHATTER_THRESHOLD = 0.5   # indicator above: the block chatters (unless its vibration dies out)
DECAY_LIMIT = 1.0         # growth x run length at or below -this: a dying transient, not chatter

__all__ = ["ChatterResult", "CHATTER_THRESHOLD", "DECAY_LIMIT", "analyse", "growth_rate", "indicator",
           "in_cut_runs"]


@dataclass(frozen=True)
class ChatterResult:
    indicator: float   # 0..1; NaN: too few in-cut tooth periods or no vibration
    growth: float      # 1/s; NaN as the indicator
    samples: int       # in-cut samples analysed
    duration: float = math.nan  # s: the run the growth rate is fitted over

    @property
    def dies_out(self) -> bool:
        """The vibration shrinks by a factor e or more over the run (NaN growth: not known to)."""
        return bool(self.growth * self.duration <= -DECAY_LIMIT)

    @property
    def chatter(self) -> bool:
        return bool(self.indicator > CHATTER_THRESHOLD) and not self.dies_out


def _energies(dx: np.ndarray, dy: np.ndarray, fs: float, f_tp: float) -> tuple[float, float]:
    """(energy outside the harmonic bands, energy from f_tp / 2 up), of the Hann-windowed spectra."""
    n = dx.size
    window = np.hanning(n)
    power = (np.abs(np.fft.rfft((dx - dx.mean()) * window)) ** 2
             + np.abs(np.fft.rfft((dy - dy.mean()) * window)) ** 2)
    f = np.fft.rfftfreq(n, 1.0 / fs)
    df = fs / n
    considered = f >= 0.5 * f_tp
    k = np.maximum(np.rint(f / f_tp), 1.0)
    harmonic = np.abs(f - k * f_tp) <= np.maximum(HARMONIC_BAND * k * f_tp, 2.0 * df)
    total = float(power[considered].sum())
    return float(power[considered & ~harmonic].sum()), total


def indicator(t: np.ndarray, dx: np.ndarray, dy: np.ndarray, tooth_frequency: float) -> float:
    """The share of the vibration energy away from the tooth-passing harmonics (module text); t evenly spaced."""
    if t.size < MIN_SAMPLES or not tooth_frequency > 0:
        return math.nan
    off, total = _energies(dx, dy, 1.0 / float(np.median(np.diff(t))), tooth_frequency)
    return off / total if total > 0 else math.nan


def growth_rate(t: np.ndarray, dx: np.ndarray, dy: np.ndarray, tooth_frequency: float) -> float:
    """Slope of the log RMS displacement over successive whole tooth periods (1/s; module text)."""
    if not tooth_frequency > 0:
        return math.nan
    period = 1.0 / tooth_frequency
    window = np.floor((t - t[0]) / period).astype(np.int64)
    count = int(window[-1])  # the last, incomplete period is left out
    if count < MIN_TOOTH_PERIODS:
        return math.nan
    keep = window < count
    r2 = (dx - dx.mean()) ** 2 + (dy - dy.mean()) ** 2
    sums = np.bincount(window[keep], weights=r2[keep], minlength=count)
    samples = np.bincount(window[keep], minlength=count)
    valid = (samples > 0) & (sums > 0)
    if valid.sum() < MIN_TOOTH_PERIODS:
        return math.nan
    log_rms = 0.5 * np.log(sums[valid] / samples[valid])
    mid = t[0] + (np.flatnonzero(valid) + 0.5) * period
    return float(np.polyfit(mid, log_rms, 1)[0])


def in_cut_runs(in_cut: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) of the runs of consecutive True values (stop exclusive)."""
    edges = np.diff(np.r_[0, in_cut.astype(np.int8), 0])
    return list(zip(np.flatnonzero(edges == 1).tolist(), np.flatnonzero(edges == -1).tolist()))


def analyse(t: np.ndarray, dx: np.ndarray, dy: np.ndarray, in_cut: np.ndarray, spindle_speed: float,
            n_flutes: int) -> ChatterResult:
    """The indicator and growth rate of one block. ``spindle_speed`` in rad/s (its magnitude is used); the
    in-cut samples may form several runs: the indicator sums their energies, the growth rate is the longest
    run's."""
    f_tp = n_flutes * abs(spindle_speed) / (2.0 * math.pi)
    runs = [(a, b) for a, b in in_cut_runs(in_cut) if b - a >= MIN_SAMPLES]
    samples = sum(b - a for a, b in runs)
    if not runs or not f_tp > 0 or samples == 0:
        return ChatterResult(math.nan, math.nan, samples)
    covered = sum(float(t[b - 1] - t[a]) for a, b in runs)
    if covered * f_tp < MIN_TOOTH_PERIODS:
        return ChatterResult(math.nan, math.nan, samples)
    off = total = 0.0
    for a, b in runs:
        fs = 1.0 / float(np.median(np.diff(t[a:b])))
        o, e = _energies(dx[a:b], dy[a:b], fs, f_tp)
        off, total = off + o, total + e
    a, b = max(runs, key=lambda r: r[1] - r[0])
    value = off / total if total > 0 else math.nan
    return ChatterResult(value, growth_rate(t[a:b], dx[a:b], dy[a:b], f_tp) if total > 0 else math.nan, samples,
                         float(t[b - 1] - t[a]))
