"""Stability lobes (models/stability.py): the zero-order solution against Tlusty's single-mode limit, the
semi-discretization against the zero-order solution where it is exact and against the impulse model of
highly interrupted cutting."""
from __future__ import annotations

import math
import time

import numpy as np
import pytest

from milling_twin.models import stability
from milling_twin.models.stability import (Mode, SemiDiscretization, directional_factors, frf,
                                           semi_discretization_limit, semi_discretization_lobes,
                                           stability_lobes, step_directional_matrices)

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


# --- ZOA regression: the limit scales with the stiffness whatever its size ------------------------------------

def test_zero_order_limit_scales_with_stiffness_for_stiff_tools() -> None:
    """a_lim is proportional to the modal stiffness (the FRF is 1/k times a shape). An absolute tolerance on a0
    (in m^2/N^2) once dropped the x-y coupling for stiff tools: 4.88 mm instead of 1.03 mm at 2800 Hz, 2e7 N/m."""
    base = Mode(2800.0, 0.03, 2e5)
    reference = stability_lobes((base,), (base,), KTC, KRC, n_flutes=3).limit([9500.0, 10000.0])
    for scale in (1e-2, 1.0, 1e2, 1e4):
        mode = Mode(base.frequency, base.damping, base.stiffness * scale)
        limit = stability_lobes((mode,), (mode,), KTC, KRC, n_flutes=3).limit([9500.0, 10000.0])
        assert limit == pytest.approx(reference * scale, rel=1e-9)
    mode = Mode(2800.0, 0.03, 2e7)
    lowest = np.nanmin(stability_lobes((mode,), (mode,), 767.01e6, 168.8e6, n_flutes=3, points=20000).depth)
    # symmetric tool in slotting: a_min = 2 pi / (N Ktc max Re(lambda G)), lambda = pi (-Kr +- i) the eigenvalues
    # of the directional matrix; close to 4 k zeta / (N Ktc)
    omega = 2 * math.pi * np.linspace(2000, 3600, 400001)
    g = frf((mode,), omega)
    kr = 168.8 / 767.01
    best = max(np.max((math.pi * (-kr + sign * 1j) * g).real) for sign in (1, -1))
    assert lowest == pytest.approx(2 * math.pi / (3 * 767.01e6 * best), rel=1e-4)
    assert lowest == pytest.approx(1.034e-3, rel=2e-3)


# --- Semi-discretization ------------------------------------------------------------------------------------

def test_step_directional_matrices_average_to_the_zero_order_factors() -> None:
    """The mean of W over the tooth period is N / (4 pi) times the directional factors, for any steps count and
    immersion (slotting, down-milling, an arc across phi = 0 of the next turn)."""
    kr = KRC / KTC
    for entry, exit in ((0.0, math.pi), (2.0, math.pi), (0.3, 1.1), (5.5, 7.0)):
        for n_flutes, steps in ((2, 40), (3, 57), (4, 7)):
            w = step_directional_matrices(n_flutes, kr, entry, exit, steps)
            expected = n_flutes / (4 * math.pi) * np.reshape(directional_factors(entry, exit, kr), (2, 2))
            assert np.mean(w, axis=0) == pytest.approx(expected, abs=1e-12)


def test_time_invariant_cut_semi_discretization_equals_the_zero_order_limit() -> None:
    """With 3 flutes over a 360 deg immersion the directional matrix is constant (the harmonics of 2 phi cancel),
    so the zero-order solution is exact there: SD converges to it (m and 2 m steps, both within 0.5 %)."""
    stiff = Mode(2800.0, 0.03, 2e7)
    for mode, speed in ((MODE, 6000.0), (MODE, 10000.0), (stiff, 10000.0)):
        zoa = stability_lobes((mode,), (mode,), KTC, KRC, 3, 0.0, 2 * math.pi, lobes=80, points=40000).limit([speed])
        steps = SemiDiscretization.build((mode,), (mode,), KTC, KRC, 3, speed, 0.0, 2 * math.pi).steps
        coarse = semi_discretization_limit((mode,), (mode,), KTC, KRC, 3, speed, 0.0, 2 * math.pi, rtol=2e-4)
        fine = semi_discretization_limit((mode,), (mode,), KTC, KRC, 3, speed, 0.0, 2 * math.pi, steps=2 * steps,
                                         rtol=2e-4)
        assert coarse == pytest.approx(zoa[0], rel=5e-3) and fine == pytest.approx(zoa[0], rel=5e-3)
        assert abs(fine - zoa[0]) <= abs(coarse - zoa[0]) + 2e-4 * zoa[0]


# Insperger and Stepan's single-DOF milling example (Int. J. Numer. Meth. Engng 61 (2004); Insperger, Mann,
# Stepan, Bayly, Int. J. Mach. Tools Manuf. 43 (2003) 25-34): 2 flutes, Kt = 6e8, Kn = 2e8 N/m^2, modal mass
# 0.03993 kg, 922 Hz, damping 0.011, flexible in x only.
IS_MASS, IS_KT, IS_KN = 0.03993, 6e8, 2e8
IS_MODE = Mode(922.0, 0.011, IS_MASS * (2 * math.pi * 922.0) ** 2)


def impulse_flip_limit(speed_rpm: float, entry: float, exit: float) -> float:
    """Period-doubling limit of highly interrupted cutting (the cut as an impulse; Davies et al., J. Manuf. Sci.
    Eng. 124 (2002); Insperger et al. 2003): free vibration E = exp(A tau) between impulses that change the
    velocity by -(w H / m)(x_k - x_{k-1}), H = int h dt over one cut. The map on (x, v) after an impulse has a
    multiplier -1 at w H / m = (1 + tr E + det E) / (2 E_12)."""
    wn = 2 * math.pi * IS_MODE.frequency
    tau, omega = 60.0 / (2 * speed_rpm), 2 * math.pi * speed_rpm / 60.0
    zeta = IS_MODE.damping
    wd = wn * math.sqrt(1 - zeta ** 2)
    decay = math.exp(-zeta * wn * tau)
    trace = 2 * decay * math.cos(wd * tau)
    e12 = decay * math.sin(wd * tau) / wd

    def primitive(phi: float) -> float:  # of h(phi) = sin(phi) (Kt cos(phi) + Kn sin(phi))
        return IS_KT * 0.5 * math.sin(phi) ** 2 + IS_KN * (0.5 * phi - 0.25 * math.sin(2 * phi))

    h_integral = (primitive(exit) - primitive(entry)) / omega
    return IS_MASS * (1 + trace + decay ** 2) / (2 * e12 * h_integral)


def test_insperger_stepan_period_doubling_lobe_of_low_immersion_down_milling() -> None:
    """Down-milling with a/D = 0.002 and 0.005 at 18000 rpm (tooth frequency near 2/3 of the natural one): SD finds
    the period-doubling lobe (critical multiplier -1) at the impulse model's closed-form depth within 1 % (the cut
    lasts 2.8 and 4.5 % of the tooth period), where the zero-order solution sees no lobe at all."""
    for ratio, expected_mm in ((0.002, 26.04), (0.005, 10.57)):
        entry = math.acos(2 * ratio - 1)
        flip = impulse_flip_limit(18000.0, entry, math.pi)
        assert flip * 1e3 == pytest.approx(expected_mm, abs=0.01)
        limit = semi_discretization_limit((IS_MODE,), (), IS_KT, IS_KN, 2, 18000.0, entry, math.pi)
        assert limit == pytest.approx(flip, rel=0.01)
        sd = SemiDiscretization.build((IS_MODE,), (), IS_KT, IS_KN, 2, 18000.0, entry, math.pi)
        multipliers = np.linalg.eigvals(sd.monodromy(limit * 1.001))
        critical = multipliers[np.argmax(np.abs(multipliers))]
        assert critical.real < -0.99 and abs(critical.imag) < 1e-6
        zoa = stability_lobes((IS_MODE,), (), IS_KT, IS_KN, 2, entry, math.pi, lobes=80).limit([18000.0])[0]
        assert not zoa < 3 * flip


def test_insperger_stepan_example_converges_with_the_steps() -> None:
    """The limit with m and 2 m steps within 1 % (up-milling and down-milling a/D = 0.05, slotting)."""
    up, down = (0.0, math.acos(1 - 2 * 0.05)), (math.acos(2 * 0.05 - 1), math.pi)
    for (entry, exit), speed in ((up, 9000.0), (down, 18000.0), ((0.0, math.pi), 9000.0)):
        steps = SemiDiscretization.build((IS_MODE,), (), IS_KT, IS_KN, 2, speed, entry, exit).steps
        coarse = semi_discretization_limit((IS_MODE,), (), IS_KT, IS_KN, 2, speed, entry, exit)
        fine = semi_discretization_limit((IS_MODE,), (), IS_KT, IS_KN, 2, speed, entry, exit, steps=2 * steps)
        assert np.isfinite(coarse) and coarse == pytest.approx(fine, rel=0.01)


def test_chatter_scenario_tool_semi_discretization_near_zero_order_and_co_simulation() -> None:
    """The 922 Hz tool of scenarios/chatter.toml, 2-flute slotting at 6000 rpm: ZOA 0.0399 mm and the
    co-simulated onset 0.0380 mm (docs/validation.md); SD within 3 % of both, converged (m, 2 m within 1 %)."""
    ktc, krc = 767.01e6, 168.8e6
    sd = semi_discretization_limit((MODE,), (MODE,), ktc, krc, 2, 6000.0)
    fine = semi_discretization_limit((MODE,), (MODE,), ktc, krc, 2, 6000.0,
                                     steps=2 * SemiDiscretization.build((MODE,), (MODE,), ktc, krc, 2, 6000.0).steps)
    zoa = stability_lobes((MODE,), (MODE,), ktc, krc, 2, lobes=60).limit([6000.0])[0]
    assert sd == pytest.approx(fine, rel=0.01)
    assert sd == pytest.approx(zoa, rel=0.03) and sd == pytest.approx(0.0380e-3, rel=0.03)
    lobes = semi_discretization_lobes((MODE,), (MODE,), ktc, krc, 2, [6000.0, 11000.0])
    assert lobes[0] == sd and lobes[1] == pytest.approx(0.0382e-3, rel=0.01)


def test_one_speed_is_fast() -> None:
    mode = Mode(2800.0, 0.03, 2e7)
    start = time.process_time()
    limit = semi_discretization_limit((mode,), (mode,), 767.01e6, 168.8e6, 3, 9500.0)
    assert time.process_time() - start < 3.0  # ~0.7 s on one core; CPU time, robust to a loaded machine
    assert limit == pytest.approx(1.76e-3, rel=0.01)


def test_bad_input_names_the_value() -> None:
    with pytest.raises(ValueError, match="n_flutes=0"):
        semi_discretization_limit((MODE,), (MODE,), KTC, KRC, 0, 6000.0)
    with pytest.raises(ValueError, match="no modes"):
        semi_discretization_limit((), (), KTC, KRC, 2, 6000.0)
    with pytest.raises(ValueError, match="mode 1 in y"):
        semi_discretization_limit((MODE,), (Mode(900.0, 0.01, 0.0),), KTC, KRC, 2, 6000.0)


@pytest.mark.parametrize("radius, root, smooth", [
    (lambda a: math.exp(40 * (a - 0.3)), 0.3, True),  # log(radius) linear: false position is exact at once
    (lambda a: a ** 6 / 0.3 ** 6, 0.3, True),  # curved
    (lambda a: 0.5 + 0.5 * a / 0.37 if a < 0.37 else 1.0 + 20 * (a - 0.37), 0.37, False),  # a kink at the crossing
    (lambda a: 1.0 - 0.02 * (0.33 - a) if a < 0.33 else 1.0 + 1e-4 * (a - 0.33), 0.33, False),  # flat above
])
def test_the_radius_crossing_brackets_the_root_within_rtol_in_fewer_radii_than_bisection(radius, root,
                                                                                          smooth) -> None:
    """Fewer radii than bisection where log(radius) is smooth, at most twice as many at a kink."""
    from milling_twin.models.stability import _radius_crossing

    calls = []

    def counted(a: float) -> float:
        calls.append(a)
        return radius(a)

    low, high = 0.28, 0.28 * 1.25 ** 2  # a bracket as the rise leaves it
    found = _radius_crossing(counted, low, radius(low), high, radius(high), 1e-3)
    assert abs(found - root) <= 0.5e-3 * found
    stable = [a for a in calls if radius(a) < 1.0]
    unstable = [a for a in calls if radius(a) >= 1.0]
    assert stable and unstable and min(unstable) - max(stable) <= 1e-3 * min(unstable)  # a closed bracket
    bisection = math.ceil(math.log2((high - low) / (1e-3 * root)))
    assert len(calls) <= (bisection - 2 if smooth else 2 * bisection)
