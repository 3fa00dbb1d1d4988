"""The model-free reference of leave-one-feed-out (orchestrator/calibrate/feed_interpolant.py): the phase search,
the claim that a law linear in the chip through a linear measuring chain is affine in the feed at every angle (so
the affine interpolant predicts every held-out feed of such recordings, the end feeds too), and what it cannot do
for a law curved in the chip."""
from __future__ import annotations

import math

import numpy as np
import pytest

from milling_twin.models.cutting_force import CHIP_LAW_EXPONENTIAL, CHIP_LAW_LINEAR, CUTTING_FORCE
from milling_twin.models.measuring_chain import frequency_response
from milling_twin.orchestrator.calibrate.feed_interpolant import align, interpolant_folds, predict, rotate

FEEDS = (300.0, 600.0, 900.0, 1200.0, 1500.0)
PHASES = (0.4, 2.9, 5.1, 1.3, 3.7)
POINTS = 100
FINE = 800
CHAIN = {"n_modes": 1, "frequency_1": 950.0, "damping_1": 0.06, "gain_1_xx": 0.8, "gain_1_xy": 0.15,
         "gain_1_xz": 0.0, "gain_1_yx": -0.1, "gain_1_yy": 0.6, "gain_1_yz": 0.05, "gain_1_zx": 0.1,
         "gain_1_zy": 0.0, "gain_1_zz": 0.3}


def recorded(feed: float, phase: float, law: int, coefficients: dict[str, float]) -> np.ndarray:
    """One revolution at 6000 rpm from spindle angle ``phase`` as a dynamometer behind ``CHAIN`` records it
    (100 samples, 2-flute slot, the harmonics below the samples' Nyquist frequency). The force is evaluated from
    angle 0 and its spectrum turned: the 16 axial slices' steps alias on any grid, differently from another start,
    and the recordings of one feed are to be exact turns of each other."""
    angle = 2 * math.pi * np.arange(FINE) / FINE
    out = CUTTING_FORCE.evaluate(**coefficients, chip_law=law, n_flutes=2, tool_diameter=0.025,
                                 helix_angle=math.radians(30), spindle_speed=200 * math.pi,
                                 feed_velocity_x=feed / 60_000, axial_depth=0.003, angle=angle,
                                 delayed_displacement_x=0.0, delayed_displacement_y=0.0)
    spectrum = np.fft.rfft(np.column_stack([out["Fy"], out["Fx"], out["Fz"]]), axis=0)
    kept = np.zeros_like(spectrum)
    kept[:50] = np.einsum("kij,kj->ki", frequency_response(CHAIN, np.arange(50) * 100.0), spectrum[:50])
    return np.fft.irfft(rotate(kept, phase), n=FINE, axis=0)[::FINE // POINTS]


LINEAR = {"Ktc": 800e6, "Krc": 100e6, "Kac": 60e6, "Kte": 30e3, "Kre": 35e3, "Kae": 25e3}
EXPONENTIAL = {"Ktc": 420e6, "Krc": 160e6, "Kac": 90e6, "mc_t": 0.25, "mc_r": 0.45, "mc_a": 0.3}


def test_align_finds_the_rotation_of_a_waveform() -> None:
    wave = recorded(900.0, 0.0, CHIP_LAW_LINEAR, LINEAR)
    turned = recorded(900.0, 1.1, CHIP_LAW_LINEAR, LINEAR)
    angle = align(np.fft.rfft(wave, axis=0), np.fft.rfft(turned, axis=0))
    # turned(phi) = wave(phi + 1.1): reading it 2 pi - 1.1 later is the wave again
    # two identical flutes without runout: a turn by half a revolution is the same waveform
    assert min(abs(angle - (2 * math.pi - 1.1)), abs(angle - (math.pi - 1.1))) < 1e-9
    back = np.fft.irfft(rotate(np.fft.rfft(turned, axis=0), angle), n=POINTS, axis=0)
    assert np.abs(back - wave).max() < 1e-9 * np.ptp(wave)


def test_a_linear_law_through_a_chain_is_affine_in_the_feed_at_every_angle() -> None:
    """Every feed, the end ones too, predicted from the other four in their own phases: the interpolant of
    degree 1 holds the recordings of a law linear in the chip (no runout) through a chain with cross-coupling."""
    waves = [recorded(f, p, CHIP_LAW_LINEAR, LINEAR) for f, p in zip(FEEDS, PHASES)]
    folds = interpolant_folds(waves, FEEDS, 1)
    assert [f.held_feed for f in folds] == list(FEEDS)
    for f in folds:
        assert np.abs(f.mean_error).max() < 1e-9, f
        assert f.r2.min() > 1 - 1e-9, f


def test_a_law_curved_in_the_chip_is_not_affine_in_the_feed() -> None:
    """Kienzle's law: the affine interpolant misses the end feeds' means, the quadratic one comes closer."""
    waves = [recorded(f, p, CHIP_LAW_EXPONENTIAL, EXPONENTIAL) for f, p in zip(FEEDS, PHASES)]
    affine = interpolant_folds(waves, FEEDS, 1)
    quadratic = interpolant_folds(waves, FEEDS, 2)
    worst_affine = max(np.abs(f.mean_error).max() for f in affine)
    worst_quadratic = max(np.abs(f.mean_error).max() for f in quadratic)
    assert worst_affine > 0.02, worst_affine
    assert worst_quadratic < worst_affine / 2, (worst_quadratic, worst_affine)


def test_the_prediction_is_in_the_phase_of_the_median_feed() -> None:
    waves = [recorded(f, p, CHIP_LAW_LINEAR, LINEAR) for f, p in zip(FEEDS, PHASES)]
    middle = predict([waves[i] for i in (0, 1, 3, 4)], [FEEDS[i] for i in (0, 1, 3, 4)], 900.0, 1)
    # the median of 300, 600, 1200, 1500 by position is 1200 (index 2 of the sorted four): its phase
    assert np.abs(middle - recorded(900.0, PHASES[3], CHIP_LAW_LINEAR, LINEAR)).max() < 1e-9 * np.ptp(middle)


@pytest.mark.parametrize("feeds, degree, message", [
    ((300.0, 600.0), 2, "degree 2 in the feed needs more than 2 feeds"),
    ((300.0, 300.0, 900.0), 1, "one waveform per distinct feed"),
])
def test_bad_interpolants_are_refused(feeds: tuple[float, ...], degree: int, message: str) -> None:
    waves = [np.zeros((POINTS, 3))] * len(feeds)
    with pytest.raises(ValueError, match=message):
        predict(waves, feeds, 450.0, degree)
