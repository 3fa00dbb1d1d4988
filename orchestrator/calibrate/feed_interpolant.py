"""What the slot-milling recordings allow: a model-free reference for leave-one-feed-out.

The recorded per-revolution waveform of every feed, brought to one spindle phase, is interpolated angle by angle
as a polynomial in the feed (each harmonic per axis a complex polynomial, fitted by least squares to the other
feeds) and the held-out feed is predicted from it, its phase found as a model's is (the rotation that fits best).

Why it is the reference for the models: a chip-thickness law linear in the chip (edge and cutting terms), through
any linear time-invariant measuring chain, with any helix, tool geometry and a runout that keeps both flutes
cutting, gives a waveform that is *affine in the feed at every angle* (degree 1). Such a model is the interpolant
of degree 1 with fewer freedoms: it fits the other feeds no better, and it is not to be expected to predict the
held-out one better, except by chance. Degree 2 shows what a law curved in the chip thickness could add. The
kinematic runout chip (the thinnest surface of the flutes before) is not affine at feeds below the runout, nor is
chatter: a model with those can differ either way.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

__all__ = ["InterpolantFold", "align", "interpolant_folds", "predict", "rotate"]

PHASE_STEPS = 3600  # the phase search's grid: 0.1 degree of spindle angle, then Newton's method


@dataclass(frozen=True)
class InterpolantFold:
    """One held-out feed predicted by the interpolant of the others (the fields :func:`slot_lofo.summary`
    reads)."""

    held_feed: float
    learning_feeds: tuple[float, ...]
    degree: int
    mean_error: np.ndarray  # relative, signed, per recorded axis
    r2: np.ndarray  # per recorded axis


def rotate(spectrum: np.ndarray, angle: float) -> np.ndarray:
    """The rfft ``spectrum`` (harmonics x axes) of a waveform over one revolution, of the waveform read
    ``angle`` rad of spindle angle later: harmonic k turns by ``k * angle``."""
    k = np.arange(spectrum.shape[0])[:, None]
    return spectrum * np.exp(1j * k * angle)


def align(reference: np.ndarray, spectrum: np.ndarray) -> float:
    """The rotation (rad) that brings ``spectrum`` closest to ``reference`` in least squares, i.e. the largest
    cross-correlation summed over the axes (both rfft spectra of one revolution): the best of PHASE_STEPS
    rotations, then Newton's method on the correlation's harmonic series to the rounding of the floats."""
    product = np.sum(np.conj(reference) * spectrum, axis=1)  # per harmonic, summed over the axes
    product[1:] *= 2.0  # rfft halves: the other half of each harmonic's power (the Nyquist term is small enough)
    padded = np.zeros(PHASE_STEPS // 2 + 1, dtype=complex)
    padded[:len(product)] = product
    correlation = np.fft.irfft(padded, n=PHASE_STEPS)  # at the rotations 2 pi m / PHASE_STEPS
    angle = 2 * math.pi * int(np.argmax(correlation)) / PHASE_STEPS
    k = np.arange(len(product))
    for _ in range(8):
        turned = product * np.exp(1j * k * angle)
        slope, curvature = -float(np.sum(k * turned.imag)), -float(np.sum(k * k * turned.real))
        if curvature >= 0.0:  # not at a maximum's cap: keep the grid's best
            break
        step = -slope / curvature
        angle += float(np.clip(step, -math.pi / PHASE_STEPS, math.pi / PHASE_STEPS))
        if abs(step) < 1e-12:
            break
    return angle % (2 * math.pi)


def _scores(recorded: np.ndarray, predicted: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    rec_mean = recorded.mean(axis=0)
    error = (predicted.mean(axis=0) - rec_mean) / np.abs(rec_mean)
    r2 = 1.0 - np.sum((recorded - predicted) ** 2, axis=0) / np.sum((recorded - rec_mean) ** 2, axis=0)
    return error, r2


def predict(waves: Sequence[np.ndarray], feeds: Sequence[float], feed: float, degree: int) -> np.ndarray:
    """The waveform (points x axes) at ``feed`` from the interpolant of ``waves`` (one revolution each, the same
    number of points, any spindle phase) at ``feeds``, in the phase of the wave whose feed is the median."""
    if len(waves) != len(feeds) or len(set(feeds)) != len(feeds):
        raise ValueError(f"one waveform per distinct feed needed, got {len(waves)} for feeds {list(feeds)}")
    if not 0 <= degree < len(feeds):
        raise ValueError(f"a polynomial of degree {degree} in the feed needs more than {degree} feeds, "
                         f"got {len(feeds)}")
    points = {w.shape for w in waves}
    if len(points) != 1:
        raise ValueError(f"the waveforms differ in shape: {sorted(points)}")
    spectra = [np.fft.rfft(np.asarray(w, dtype=float), axis=0) for w in waves]
    scale = float(np.mean(feeds))
    basis = np.vander(np.asarray(feeds, dtype=float) / scale, degree + 1, increasing=True)
    # the phases: each waveform turned to the median feed's by correlation, then, since waveforms of different
    # shapes correlate best a little off their true phase, all turns at once to the least-squares misfit of the
    # interpolant (the misfit is (I - H) of the turned spectra, H the polynomial's hat matrix over the feeds; the
    # median feed's phase stays)
    order = np.argsort(feeds)
    median = int(order[len(order) // 2])
    start = np.array([align(spectra[median], s) for s in spectra])
    free = [i for i in range(len(feeds)) if i != median]
    residual_maker = np.eye(len(feeds)) - basis @ np.linalg.pinv(basis)

    def angles_of(x: np.ndarray) -> np.ndarray:
        angles = np.zeros(len(feeds))
        angles[free] = x
        return angles

    def misfit(x: np.ndarray) -> np.ndarray:
        turned = np.array([rotate(s, a) for s, a in zip(spectra, angles_of(x))]).reshape(len(feeds), -1)
        rest = residual_maker @ turned
        return np.concatenate([rest.real.ravel(), rest.imag.ravel()])

    angles = angles_of(least_squares(misfit, start[free], x_scale=1e-2, xtol=1e-14, ftol=1e-14, gtol=1e-14).x
                       if free and degree + 1 < len(feeds) else start[free])
    aligned = np.array([rotate(s, a) for s, a in zip(spectra, angles)])
    coefficients, *_ = np.linalg.lstsq(basis, aligned.reshape(len(feeds), -1), rcond=None)
    at = np.vander(np.array([feed / scale]), degree + 1, increasing=True)
    spectrum = (at @ coefficients).reshape(aligned.shape[1:])
    return np.fft.irfft(spectrum, n=waves[0].shape[0], axis=0)


def interpolant_folds(waves: Sequence[np.ndarray], feeds: Sequence[float], degree: int) -> list[InterpolantFold]:
    """Leave one feed out with the interpolant of ``degree``: per feed (ascending), its recorded waveform against
    the prediction from the others, turned to its best phase."""
    folds = []
    ascending = sorted(range(len(feeds)), key=lambda i: feeds[i])
    for held in ascending:
        others = [i for i in ascending if i != held]
        predicted = predict([waves[i] for i in others], [feeds[i] for i in others], feeds[held], degree)
        recorded = np.asarray(waves[held], dtype=float)
        spectrum = np.fft.rfft(predicted, axis=0)
        turned = np.fft.irfft(rotate(spectrum, align(np.fft.rfft(recorded, axis=0), spectrum)),
                              n=recorded.shape[0], axis=0)
        error, r2 = _scores(recorded, turned)
        folds.append(InterpolantFold(float(feeds[held]), tuple(float(feeds[i]) for i in others), degree, error, r2))
    return folds
