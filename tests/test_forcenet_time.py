"""The force FMUs do not depend on how an importer does its time arithmetic (issue 19, item 4).

Importers hand doStep the same steps in different floating-point forms: fmpy's ``simulate_fmu`` and libcosim
a communication point ``t_n = n h`` and the step ``h``; FMUChecker accumulates ``t += h``; fmusim and this
project's master pass ``t_n = n h`` with the step ``t_(n+1) - t_n`` (which differs from ``h`` in its last
bits). The outputs of ForceNet and CuttingForce must agree across all of them to 1e-9 of their amplitude on
every sample, FMI 3 and FMI 2, at a constant step and with the master's variable step (10 us in material,
1 ms in air).

The case is the one that jumped: a 2-flute slot at 6000 rpm and 10 us, so a revolution is 1000 steps and
the spindle angle returns to the window's edges (0 and 180 deg) and to 2 pi; a vibrating tool (displacement
inputs, the regenerative chip through the time-indexed history). Before ForceNet counted its own time
(fmus/common/step_clock.h), the angle accumulated the importer's step sizes, and at those
edges an element went in or out of contact on a 1-ulp difference: Fx 0 N vs 34 N at single samples (both
FMUs; both now count their own time, fmus/common/step_clock.h).
"""
from __future__ import annotations

import math
from fractions import Fraction
from typing import Callable

import numpy as np
import pytest

from fmu_helpers import OK, Slave, assert_close, fmu_dir, require_fmu
from milling_twin.models import force_net as fn
from milling_twin.models.step_clock import StepClock

FORCE_OUTPUTS = {"ForceNet": ("Fx", "Fy", "Fz", "torque", "power", "Mx", "My", "Mz"),
                 "CuttingForce": ("Fx", "Fy", "Fz", "torque", "power")}
VALUES = {"n_flutes": 2, "tool_diameter": 0.01, "helix_angle": 0.0, "spindle_speed": 6000 * 2 * math.pi / 60,
          "feed_velocity_x": 0.01, "feed_velocity_y": 0.0, "axial_depth": 1e-3, "entry_angle": 0.0,
          "exit_angle": math.pi}
FINE, COARSE = 1e-5, 1e-3  # the master's variable step: in material, in air


def constant_steps(count: int) -> list[float]:
    return [FINE] * count


def variable_steps(count: int) -> list[float]:
    """Runs of 10 us (300 of them, a third of a revolution) and 1 ms (7) in turn."""
    pattern = [FINE] * 300 + [COARSE] * 7
    return (pattern * (count // len(pattern) + 1))[:count]


def nominal_times(steps: list[float]) -> list[float]:
    """t_n: the double nearest the exact sum of the nominal (decimal) steps."""
    exact, times = Fraction(0), [0.0]
    for h in steps:
        exact += Fraction(str(h))
        times.append(float(exact))
    return times


def accumulated_times(steps: list[float]) -> list[float]:
    times = [0.0]
    for h in steps:
        times.append(times[-1] + h)
    return times


def ulp_times(steps: list[float]) -> list[float]:
    """t_n 1 ulp above or below (alternating) the nominal ones."""
    times = nominal_times(steps)
    return [0.0] + [float(np.nextafter(t, math.inf if n % 2 else -math.inf)) for n, t in enumerate(times) if n]


# How an importer turns the steps into doStep arguments: (communication points, step sizes)
Convention = Callable[[list[float]], tuple[list[float], list[float]]]


def _differences(times: list[float]) -> list[float]:
    return [b - a for a, b in zip(times, times[1:])]


CONVENTIONS: dict[str, Convention] = {
    "n*h, h": lambda steps: (nominal_times(steps), steps),                 # fmpy, libcosim
    "t+=h, h": lambda steps: (accumulated_times(steps), steps),            # FMUChecker
    "n*h+-ulp, h": lambda steps: (ulp_times(steps), steps),
    "n*h, differences": lambda steps: (nominal_times(steps), _differences(nominal_times(steps))),  # fmusim, master
    "t+=h, differences": lambda steps: (accumulated_times(steps), _differences(accumulated_times(steps))),
    "n*h+-ulp, differences": lambda steps: (ulp_times(steps), _differences(ulp_times(steps))),
}


def displacement(t: float) -> tuple[float, float]:
    """A tool vibrating at 922 Hz (ToolVibration's mode), a few um: the chip is regenerative."""
    return 5e-6 * math.sin(2 * math.pi * 922.0 * t), 4e-6 * math.cos(2 * math.pi * 922.0 * t + 0.3)


def run(identifier: str, version: int, steps: list[float], convention: str) -> np.ndarray:
    """Outputs (forces and spindle angle) after every step; the inputs at step n are those of the nominal time,
    the same in every convention."""
    name = f"{identifier}.fmu" if version == 3 else f"{identifier}_fmi2.fmu"
    times, sizes = CONVENTIONS[convention](steps)
    nominal = nominal_times(steps)
    outputs = [*FORCE_OUTPUTS[identifier], "spindle_angle"]
    with Slave(require_fmu(fmu_dir() / name)) as slave:
        slave.instantiate()
        slave.initialize(VALUES)
        rows = []
        for n, (t, h) in enumerate(zip(times, sizes)):
            x, y = displacement(nominal[n])
            slave.set({"displacement_x": x, "displacement_y": y})
            assert slave.step(h, t) == OK, slave.messages[-3:]
            rows.append(slave.get(outputs))
    return np.array(rows)


def disagreement(actual: np.ndarray, expected: np.ndarray) -> tuple[float, int]:
    """Largest difference of the forces relative to each one's amplitude over the run (the spindle angle: in
    rad, modulo 2 pi), and the number of samples over 1e-9."""
    forces = np.abs(actual[:, :-1] - expected[:, :-1]) / np.abs(expected[:, :-1]).max(axis=0)
    turn = np.mod(actual[:, -1] - expected[:, -1] + math.pi, 2 * math.pi) - math.pi
    every = np.column_stack([forces, np.abs(turn)])
    return float(every.max()), int(np.count_nonzero(every.max(axis=1) > 1e-9))


RUNS = {"constant": constant_steps(5000), "variable": variable_steps(5000)}
_REFERENCES: dict[tuple, np.ndarray] = {}


def reference(identifier: str, version: int, kind: str) -> np.ndarray:
    key = (identifier, version, kind)
    if key not in _REFERENCES:
        _REFERENCES[key] = run(identifier, version, RUNS[kind], "n*h, h")
    return _REFERENCES[key]


@pytest.mark.parametrize("kind", sorted(RUNS))
@pytest.mark.parametrize("convention", [c for c in CONVENTIONS if c != "n*h, h"])
@pytest.mark.parametrize("version", [3, 2])
@pytest.mark.parametrize("identifier", ["ForceNet", "CuttingForce"])
def test_outputs_agree_across_time_arithmetic(identifier: str, version: int, convention: str, kind: str) -> None:
    expected = reference(identifier, version, kind)
    assert np.count_nonzero(expected[:, 0]) > len(expected) // 3  # it cuts
    worst, samples = disagreement(run(identifier, version, RUNS[kind], convention), expected)
    assert worst <= 1e-9, f"{samples} samples differ, up to {worst:.3g} of the amplitude"


@pytest.mark.parametrize("identifier", ["ForceNet", "CuttingForce"])
def test_fmi3_and_fmi2_give_the_same_forces(identifier: str) -> None:
    assert np.array_equal(reference(identifier, 3, "variable"), reference(identifier, 2, "variable"))


# ---- the step clock (models/step_clock.py, the Python twin of fmus/common/step_clock.h) ----

def test_whole_nanosecond_steps_are_taken_exactly_whatever_their_last_bits() -> None:
    """A step of whole nanoseconds is taken as the double nearest its decimal value, whether the importer
    passed that or a difference of two communication points; the clock's time is then the same too."""
    steps = variable_steps(3000)
    clocks = {}
    for convention in ("n*h, h", "t+=h, differences", "n*h+-ulp, differences"):
        times, sizes = CONVENTIONS[convention](steps)
        clock = StepClock()
        taken = [clock.advance(t, h) for t, h in zip(times, sizes)]
        assert taken == steps, convention
        clocks[convention] = (clock.ns, clock.rest, clock.seconds())
    assert len(set(clocks.values())) == 1
    assert clocks["n*h, h"][:2] == (float(sum(round(h * 1e9) for h in steps)), 0.0)


def test_other_steps_are_taken_as_given_and_the_time_keeps_them_exactly() -> None:
    """Steps that are no whole nanoseconds (1/3 ms, 0.3 ns) are taken as given; the clock keeps what they have
    beyond whole nanoseconds, so its time does not drift from the exact sum."""
    for h, count in ((1e-3 / 3, 30000), (3e-10, 1000), (1e-5 + 2.5e-13, 10000)):
        clock, t = StepClock(), 0.0
        for _ in range(count):
            assert clock.advance(t, h) == h
            t += h
        exact = Fraction(h) * count
        assert abs(Fraction(clock.seconds()) - exact) <= 4 * Fraction(math.ulp(float(exact))), h
        assert abs(clock.rest) <= 0.5e-9


def test_the_fmu_takes_a_step_1_ulp_off_10_us_as_10_us() -> None:
    """The FMU's clock: steps of 1 ulp more than 10 us give bit for bit the outputs of 10 us steps (the angle
    and the history's sample times), and ForceNetReference, which runs models/step_clock.py, equals the FMU."""
    path = require_fmu(fmu_dir() / "ForceNet.fmu")
    for sizes in ([FINE] * 50, [float(np.nextafter(FINE, 1.0))] * 50):
        with Slave(path) as slave:
            slave.instantiate()
            slave.initialize(VALUES)
            rows = []
            for n, h in enumerate(sizes):
                slave.set(dict(zip(("displacement_x", "displacement_y"), displacement(n * FINE))))
                assert slave.step(h) == OK
                rows.append(slave.get(["Fx", "spindle_angle"]))
        if sizes[0] == FINE:
            first = np.array(rows)
        else:
            assert np.array_equal(np.array(rows), first)
    reference = fn.ForceNetReference(VALUES)
    expected = []
    for n in range(50):
        reference.set(dict(zip(("displacement_x", "displacement_y"), displacement(n * FINE))))
        row = reference.step(float(np.nextafter(FINE, 1.0)))
        expected.append([row[fn.OUTPUTS.index("Fx")], row[fn.OUTPUTS.index("spindle_angle")]])
    assert_close(first, np.array(expected))
