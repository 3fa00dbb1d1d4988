"""Zero-order stability lobes (models/stability.py) against Tlusty's single-mode limit."""
from __future__ import annotations

import math

import numpy as np
import pytest

from milling_twin.models.stability import Mode, directional_factors, frf, stability_lobes

KTC, KRC = 796e6, 168.8e6  # N/m^2 (Altintas' Al7075 example, Kr = 0.212)
MODE = Mode(922.0, 0.011, 1.34e6)


def test_slotting_directional_factors() -> None:
    axx, axy, ayx, ayy = directional_factors(0.0, math.pi, KRC / KTC)
    kr = KRC / KTC
    assert (axx, axy, ayx, ayy) == pytest.approx((-math.pi * kr, -math.pi, math.pi, -math.pi * kr))


def test_single_mode_minimum_equals_the_oriented_sdof_limit() -> None:
    """One mode in x only: a_lim = 2 pi / (N Ktc alpha_xx G) with G the FRF's real part; its
    minimum over speed uses the extreme of G with the sign of alpha_xx (a_lim > 0)."""
    lobes = stability_lobes((MODE,), (), KTC, KRC, n_flutes=2, lobes=30, points=20000)
    axx = directional_factors(0.0, math.pi, KRC / KTC)[0]
    omega = 2 * math.pi * np.linspace(800, 1100, 200001)
    g_extreme = np.min(frf((MODE,), omega).real) if axx < 0 else np.max(frf((MODE,), omega).real)
    expected = 2 * math.pi / (2 * KTC * abs(axx) * abs(g_extreme))
    assert np.nanmin(lobes.depth) == pytest.approx(expected, rel=1e-4)
    closed_form = 8 * MODE.stiffness * MODE.damping * (1 + MODE.damping) / (2 * KTC * abs(axx) / math.pi)
    assert expected == pytest.approx(closed_form, rel=2e-3)  # Tlusty: G_min ~ -1/(4 k zeta (1 + zeta))


def test_limit_is_the_lowest_lobe_and_lobes_repeat_with_tooth_frequency() -> None:
    lobes = stability_lobes((MODE,), (MODE,), KTC, KRC, n_flutes=2)
    speeds = np.linspace(4000, 30000, 300)
    limit = lobes.limit(speeds)
    assert np.all(np.isfinite(limit)) and np.all(limit >= np.nanmin(lobes.depth) * (1 - 1e-9))
    # the best speed of lobe 0 (the highest-speed lobe): tooth frequency near the natural frequency
    best = speeds[np.argmax(limit)]
    assert 60 * MODE.frequency / 2 * 0.8 < best < 60 * MODE.frequency / 2 * 1.3
