"""The output dependencies every built FMU declares (<ModelStructure>) are exactly those it has.

FMI's "dependencies" are direct: an output depends on a known if its value at the same communication point (or in
Initialization Mode, for <InitialUnknowns>) changes with the known's value, without a step in between. The FMUs
recompute their outputs when a variable is set, so the test sets one known at a time to a perturbed value and reads
every output again, at a communication point reached after some steps (branching from an FMU state, so every
perturbation starts from the same point) and in Initialization Mode. A declared-independent output must keep its
value exactly (nothing is integrated between set and get); a declared dependency must show at one of the operating
points at least. Knowns: inputs (and, in FMI 3, tunable parameters) at a communication point, inputs and parameters
in Initialization Mode. An array counts as one known, perturbed as a whole (FMI 2 lists all its elements).
"""
from __future__ import annotations

from pathlib import Path

import fmpy
import numpy as np
import pytest

from fmu_helpers import Slave, all_fmus, fmu_id, model_of, random_arguments, require_fmu, row, split_fmu_name

FMUS = all_fmus()
POINTS = 6  # operating points per FMU (random, within the variables' ranges, every Boolean value among them)
STEPS = 20  # steps before the communication point looked at


@pytest.fixture(params=FMUS, ids=fmu_id)
def fmu(request) -> Path:
    return require_fmu(request.param)


def _group(name: str) -> str:
    """An FMI 2 array element ("engagement[1,2]") stands for its array."""
    return name.split("[")[0]


def declared(path: Path) -> tuple[dict[str, set[str]], dict[str, set[str]]]:
    """Output -> declared knowns, at a communication point and in Initialization Mode (arrays by their name)."""
    md = fmpy.read_model_description(str(path))
    result = []
    for unknowns in (md.outputs, md.initialUnknowns):
        table: dict[str, set[str]] = {}
        for u in unknowns:
            assert u.dependencies is not None, f"{path.name}: {u.variable.name} declares no dependencies"
            table.setdefault(_group(u.variable.name), set()).update(_group(d.name) for d in u.dependencies)
        result.append(table)
    return result[0], result[1]


def _perturbed(v, value: float | np.ndarray, k: int) -> float | np.ndarray | None:
    """A different valid value of variable ``v`` (models.definition.Variable) near ``value``; ``k`` picks one of a
    few perturbations (of different sizes, for outputs that are flat in a small neighbourhood)."""
    if v.type == "Boolean":
        return 0.0 if value else 1.0
    if v.type == "Int32":
        lo, hi = int(v.min if v.min is not None else -1000), int(v.max if v.max is not None else 1000)
        step = 1 + k
        candidate = int(value) + step if int(value) + step <= hi else int(value) - step
        return float(candidate) if lo <= candidate <= hi and candidate != int(value) else None
    lo = v.min if v.min is not None else -np.inf
    hi = v.max if v.max is not None else np.inf
    if v.shape:  # a map: everywhere its min, max or middle (its cells may count only beyond a threshold)
        new = np.full(v.size, (lo, hi, (lo + hi) / 2)[k % 3], dtype=float)
        return None if np.array_equal(new, value) or not np.all(np.isfinite(new)) else new
    span = (hi - lo) if np.isfinite(hi - lo) else max(1.0, float(np.max(np.abs(value))))
    delta = span * (1e-4, 1e-2, 1e-1)[k % 3]
    up = np.asarray(value, dtype=float) + delta
    down = np.asarray(value, dtype=float) - delta
    new = np.where(up <= hi, up, down)
    new = np.clip(new, lo, hi)
    if np.all(new == value):
        return None
    return new if np.ndim(value) else float(new)


class Probe:
    """One instance at an operating point: set a known, read all outputs."""

    def __init__(self, slave: Slave, model, point: dict[str, float]):
        self.slave, self.model, self.point = slave, model, point
        self.outputs = [v.name for v in model.of("output")]

    def read(self) -> dict[str, np.ndarray]:
        return {name: np.atleast_1d(self.slave.get([name])) for name in self.outputs}

    def value(self, name: str) -> float | np.ndarray:
        v = self.model.variable(name)
        if v.shape:
            return np.full(v.size, float(v.start))
        return self.point.get(name, v.start)

    def set(self, name: str, value: float | np.ndarray) -> None:
        v = self.model.variable(name)
        if v.shape:
            vrs = self.slave.elements.get(name) or [self.slave.vr[name]]
            self.slave.set_real(vrs, list(np.ravel(value)))
        else:
            self.slave.set({name: value})

    def changed(self, name: str, restore) -> set[str]:
        """The outputs that change when known ``name`` is set to any of a few perturbed values."""
        v = self.model.variable(name)
        before = self.read()
        seen: set[str] = set()
        for k in range(3):
            value = _perturbed(v, self.value(name), k)
            if value is None:
                continue
            self.set(name, value)
            after = self.read()
            seen |= {o for o in self.outputs if not np.array_equal(before[o], after[o], equal_nan=True)}
            restore(name)
            again = self.read()
            assert all(np.array_equal(before[o], again[o], equal_nan=True) for o in self.outputs), \
                f"{name}: the outputs do not come back with the value"
            if v.type == "Boolean":
                break
        return seen


def knowns(model, fmi: int, initial: bool) -> list[str]:
    """What a master may set there: inputs; in Initialization Mode every numeric parameter too (String ones, file
    names, are read when initialization ends); at a communication point the tunable parameters (FMI 3 lists
    them; FMI 2 knows only inputs there, so the test perturbs its tunable parameters too, expecting the same as
    FMI 3 declares)."""
    names = [v.name for v in model.of("input")]
    for v in model.of("parameter"):
        if v.type == "String":
            continue
        if initial or v.effective_variability == "tunable":
            names.append(v.name)
    return names


def ramp(model, point: dict[str, float], before: int) -> dict[str, float]:
    """The point with its Float64 inputs ``before`` steps earlier on a ramp of 0.1 % per step (within range)."""
    moved = dict(point)
    for v in model.of("input"):
        if v.type == "Float64" and not v.shape and v.name in point:
            value = point[v.name] * (1.0 - 1e-3 * before)
            moved[v.name] = float(np.clip(value, v.min if v.min is not None else -np.inf,
                                          v.max if v.max is not None else np.inf))
    return moved


def observe(path: Path) -> tuple[dict[str, set[str]], dict[str, set[str]]]:
    """Output -> the knowns whose perturbation changed it, over POINTS operating points, at a communication point
    after STEPS steps and in Initialization Mode."""
    model = model_of(path)
    _, fmi = split_fmu_name(path)
    values = random_arguments(model, POINTS + 2, np.random.default_rng(19))
    booleans = [v.name for v in model.of("parameter") + model.of("input") if v.type == "Boolean"]
    step = {v.name: set() for v in model.of("output")}
    initial = {v.name: set() for v in model.of("output")}
    h = model.default_step_size
    for i in range(POINTS + 2):
        point = row(values, i)
        if i >= 2:  # the random points take every combination of the Booleans in turn (the corners: all 0, all 1)
            point.update({name: float((i - 2) >> b & 1) for b, name in enumerate(booleans)})
        with Slave(path) as slave:
            slave.instantiate()
            slave.enter_initialization()
            slave.set(point)
            probe = Probe(slave, model, point)
            for name in knowns(model, fmi, initial=True):
                for output in probe.changed(name, lambda n: probe.set(n, probe.value(n))):
                    initial[output].add(name)
            slave.exit_initialization()
            for k in range(STEPS):  # the inputs ramp into the point, so rates kept as states are not 0
                slave.set(ramp(model, point, STEPS - 1 - k), include_fixed=False)
                assert slave.step(h) <= 1, slave.messages[-3:]
            state = slave.fmu.getFMUState()

            def restore(_name: str) -> None:
                slave.set_state(state)

            for name in knowns(model, fmi, initial=False):
                for output in probe.changed(name, restore):
                    step[output].add(name)
            slave.fmu.freeFMUState(state)
    return step, initial


def test_declared_dependencies_are_the_observed_ones(fmu: Path) -> None:
    model = model_of(fmu)
    _, fmi = split_fmu_name(fmu)
    declared_step, declared_initial = declared(fmu)
    observed_step, observed_initial = observe(fmu)
    tunable = {v.name for v in model.of("parameter") if v.effective_variability == "tunable"}
    problems = []
    for output in observed_step:
        expected = observed_step[output] if fmi == 3 else observed_step[output] - tunable
        if declared_step[output] != expected:
            problems.append(f"at a communication point, {output}: missing {sorted(expected - declared_step[output])}"
                            f", extra {sorted(declared_step[output] - expected)}")
        if declared_initial[output] != observed_initial[output]:
            problems.append(f"in Initialization Mode, {output}: missing "
                            f"{sorted(observed_initial[output] - declared_initial[output])}, extra "
                            f"{sorted(declared_initial[output] - observed_initial[output])}")
    assert not problems, f"{fmu.name}:\n" + "\n".join(problems)


def test_the_issue_facts() -> None:
    """The structure a master needs to see that force and vibration form no algebraic loop, and that the spindle
    power does not wait for the material removal rate."""
    from milling_twin.models import MODELS

    vibration = MODELS["ToolVibration"].direct_dependencies()
    for axis in "xy":
        for name in (f"tip_displacement_{axis}", f"tip_velocity_{axis}", f"sensor_displacement_{axis}"):
            assert f"force_{axis}" not in vibration[name], name
        assert f"force_{axis}" in vibration[f"tip_acceleration_{axis}"]
    assert "mrr" not in MODELS["SpindlePower"].direct_dependencies()["P_spindle"]
    assert "displacement_x" in MODELS["CuttingForce"].direct_dependencies()["Fx"]


def test_a_native_output_without_a_declaration_is_refused() -> None:
    import dataclasses

    from milling_twin.models import MODELS
    from milling_twin.models.codegen import model_description_fmi3

    model = MODELS["Workpiece"]
    undeclared = dataclasses.replace(model, native_dependencies=model.native_dependencies[1:], _cache={})
    with pytest.raises(ValueError, match=r"Workpiece\.axial_depth is computed by model\.c"):
        model_description_fmi3(undeclared)
    wrong = dataclasses.replace(model, native_dependencies=(("axial_depth", ("no_such_input",)),
                                                            *model.native_dependencies[1:]), _cache={})
    with pytest.raises(ValueError, match=r"Workpiece\.axial_depth: native_dependencies names \['no_such_input'\]"):
        model_description_fmi3(wrong)
