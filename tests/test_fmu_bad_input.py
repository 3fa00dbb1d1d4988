"""Rejected calls and values, the error state, FMU state snapshots and instance independence, on both
FMI versions of every FMU. Each rejected call must return the documented status and log a message
naming the function and the problem (captured through the importer's logger callback)."""
from __future__ import annotations

import ctypes
import math
import shutil
import time
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from fmpy.fmi1 import FMICallException

from milling_twin.models import MODELS
from fmpy.fmi3 import fmi3Float64, fmi3ValueReference

from fmu_helpers import (
    ERROR,
    OK,
    WARNING,
    Slave,
    all_fmus,
    assert_close,
    expected_outputs,
    reference_trajectory,
    fmu_dir,
    fmu_id,
    keeps_heap_data,
    model_of,
    output_names,
    random_arguments,
    require_fmu,
    row,
    scalar_inputs,
    split_fmu_name,
    status_of,
)

FMUS = all_fmus()
POWER_FMUS = [p for p in FMUS if split_fmu_name(p)[0] == "SpindlePower"]
FMI3_FMUS = [p for p in FMUS if split_fmu_name(p)[1] == 3]

# Per model: out-of-range values (variable, value, the message's "= value ... [min, max] unit" part),
# a Float64 input for NaN/Inf, a Boolean input.
CASES = {
    "SpindlePower": {
        "out_of_range": [
            ("c3", 10.0, "= 10 is out of its allowed range [0.1, 3]"),
            ("c3", 0.05, "= 0.05 is out of its allowed range [0.1, 3]"),
            ("P_idle", -1.0, "= -1 W is out of its allowed range [0, 100000] W"),
            ("c2", 1.5e6, "= 1500000 W is out of its allowed range [0, 1000000] W"),
            ("mrr", -1e-9, "= -1e-09 m3/s is out of its allowed range [0, 0.01] m3/s"),
            ("spindle_speed", 10000.5, "= 10000.5 rad/s is out of its allowed range [-10000, 10000] rad/s"),
        ],
        "real_input": "mrr",
        "boolean_input": "spindle_on",
    },
    "MrrEstimator": {
        "out_of_range": [
            ("width_of_cut", 1.0, "= 1 m is out of its allowed range [0, 0.5] m"),
            ("depth_of_cut", -0.1, "= -0.1 m is out of its allowed range [0, 0.2] m"),
            ("feed_velocity_x", 11.0, "= 11 m/s is out of its allowed range [-10, 10] m/s"),
            ("feed_velocity_y", -10.25, "= -10.25 m/s is out of its allowed range [-10, 10] m/s"),
        ],
        "real_input": "feed_velocity_x",
        "boolean_input": "cutting",
    },
}



def c_number(x: float) -> str:
    """As the wrapper prints numbers: the shortest of %.15g..%.17g that reads back exactly."""
    for precision in (15, 16, 17):
        text = f"%.{precision}g" % x
        if float(text) == x:
            return text
    return text


def derived_case(identifier: str) -> dict:
    """Cases from the model definition, for models without hand-written ones above: one value
    above the maximum and one below the minimum of the first few ranged variables."""
    model = MODELS[identifier]
    ranged = [v for v in model.variables if v.causality in ("parameter", "input") and v.type != "Boolean"
              and v.min is not None and v.max is not None and not v.shape][:3]
    out_of_range = []
    for v in ranged:
        span = v.max - v.min
        for value in (v.max + max(1.0, span), v.min - max(1.0, span)):
            value = float(int(value)) if v.type == "Int32" else value
            unit = f" {v.unit}" if v.unit else ""
            out_of_range.append((v.name, value, f"= {c_number(value)}{unit} is out of its allowed range "
                                               f"[{c_number(v.min)}, {c_number(v.max)}]{unit}"))
    inputs = [v for v in model.variables if v.causality == "input" and not v.shape]
    return {
        "out_of_range": out_of_range,
        "real_input": next(v.name for v in inputs if v.type == "Float64"),
        "boolean_input": next((v.name for v in inputs if v.type == "Boolean"), None),
    }


for _identifier in MODELS:
    CASES.setdefault(_identifier, derived_case(_identifier))

OUT_OF_RANGE = [(p, case) for p in FMUS for case in CASES[split_fmu_name(p)[0]]["out_of_range"]]


@pytest.fixture(params=FMUS, ids=fmu_id)
def fmu(request) -> Path:
    return require_fmu(request.param)


@pytest.fixture
def slave(fmu: Path):
    with Slave(fmu) as s:
        s.instantiate()
        yield s


def set_name(slave: Slave, variable: str | None = None) -> str:
    """The FMI setter for ``variable``'s type (default Float64)."""
    kind = slave.variables[variable].type if variable else "Float64"
    if kind in ("Integer", "Int32"):
        return f"{slave.prefix}SetInteger" if slave.fmi_version == 2 else "fmi3SetInt32"
    return f"{slave.prefix}SetReal" if slave.fmi_version == 2 else "fmi3SetFloat64"


def get_name(slave: Slave) -> str:
    return f"{slave.prefix}GetReal" if slave.fmi_version == 2 else "fmi3GetFloat64"


def run_points(slave: Slave, points: list[dict], step_size: float = 1e-3) -> np.ndarray:
    names = output_names(model_of(slave.path))
    rows = []
    for point in points:
        slave.set(point, include_fixed=False)
        assert slave.step(step_size) in (OK, WARNING), slave.messages[-2:]
        rows.append(slave.get(names))
    return np.array(rows)


def random_points(fmu: Path, count: int, seed: int) -> list[dict]:
    values = random_arguments(model_of(fmu), count, np.random.default_rng(seed))
    return [row(values, i) for i in range(count)]


# ---- call sequence ----


def test_do_step_before_initialization_is_an_illegal_call(slave: Slave) -> None:
    p = slave.prefix
    assert slave.step(1e-3) == ERROR
    assert slave.messages[-1].category == "logStatusError"
    assert slave.last_error() == f"{p}DoStep: illegal call sequence: not allowed in state Instantiated"
    assert len(slave.errors()) == 1


def test_do_step_in_initialization_mode_is_an_illegal_call(slave: Slave) -> None:
    slave.enter_initialization()
    assert slave.step(1e-3) == ERROR
    assert slave.last_error() == f"{slave.prefix}DoStep: illegal call sequence: not allowed in state InitializationMode"


def test_fmpy_raises_with_the_error_status(slave: Slave) -> None:
    with pytest.raises(FMICallException) as raised:
        slave.fmu.doStep(0.0, 1e-3)
    assert raised.value.status == ERROR
    assert raised.value.function == f"{slave.prefix}DoStep"
    assert "illegal call sequence" in slave.last_error()


# ---- doStep arguments ----


def test_wrong_communication_point_is_rejected(slave: Slave) -> None:
    slave.initialize()
    assert slave.step(1e-3) == OK
    assert slave.step(1e-3, current_time=0.5) == ERROR
    assert slave.last_error() == (f"{slave.prefix}DoStep: currentCommunicationPoint = 0.5 s does not match "
                                  "the instance time 0.001 s")


def test_communication_point_rounding_is_tolerated(slave: Slave) -> None:
    slave.initialize()
    t = 0.0
    for _ in range(10):  # t += h accumulates rounding; 0.1 + 0.2 != 0.3
        assert slave.step(0.1, current_time=t) == OK
        t += 0.1
    assert slave.get(["time"])[0] == pytest.approx(1.0, rel=1e-15)
    assert not slave.errors()


@pytest.mark.parametrize("step_size", [0.0, -1e-3, math.nan, math.inf])
def test_non_positive_step_size_is_rejected(slave: Slave, step_size: float) -> None:
    slave.initialize()
    assert slave.step(step_size) == ERROR
    text = {0.0: "0", -1e-3: "-0.001", math.inf: "inf"}.get(step_size, "nan")
    assert slave.last_error() == f"{slave.prefix}DoStep: communicationStepSize = {text} s must be > 0 and finite"
    assert slave.get(["time"])[0] == 0.0


def test_step_past_stop_time_is_rejected(slave: Slave) -> None:
    slave.enter_initialization(stop_time=0.002)
    slave.exit_initialization()
    assert slave.step(1e-3) == OK
    assert slave.step(1e-3) == OK
    assert slave.step(1e-3) == ERROR
    assert "goes past stopTime" in slave.last_error()


# ---- values ----


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf], ids=["nan", "inf", "-inf"])
@pytest.mark.parametrize("mode", ["initialization", "step"])
def test_nan_and_inf_inputs_are_rejected(slave: Slave, value: float, mode: str) -> None:
    name = CASES[slave.identifier]["real_input"]
    slave.enter_initialization()
    if mode == "step":
        slave.exit_initialization()
    before = slave.get([name])[0]
    assert status_of(lambda: slave.set({name: value})) == ERROR
    assert slave.last_error() == f"{set_name(slave)}: variable '{name}' set to {value}: must be a finite number"
    assert slave.get([name])[0] == before  # not applied


@pytest.mark.parametrize("fmu, case", OUT_OF_RANGE, ids=[f"{fmu_id(p)}-{c[0]}={c[1]:g}" for p, c in OUT_OF_RANGE])
def test_out_of_range_values_are_rejected_with_their_range(fmu: Path, case: tuple) -> None:
    name, value, text = case
    with Slave(require_fmu(fmu)) as slave:
        slave.instantiate()
        assert status_of(lambda: slave.set({name: value})) == ERROR
        assert slave.last_error() == f"{set_name(slave, name)}: variable '{name}' {text}"
        slave.fmu.reset()
        slave.initialize()  # the rejected value was not applied: start values pass the checks
        assert len(slave.errors()) == 1


def test_range_limits_themselves_are_accepted(fmu: Path) -> None:
    model = model_of(fmu)
    with Slave(fmu) as slave:
        slave.instantiate()
        for bound in ("min", "max"):
            point = {v.name: getattr(v, bound) for v in model.of("parameter") + scalar_inputs(model)
                     if v.type != "Boolean" and not v.shape}
            slave.set(point)
        slave.initialize()
        assert slave.step(1e-3) in (OK, WARNING)
        assert not slave.errors()


def test_setting_an_output_or_time_is_rejected(slave: Slave) -> None:
    output = output_names(model_of(slave.path))[0]
    assert status_of(lambda: slave.set({output: 1.0})) == ERROR
    assert slave.last_error() == f"{set_name(slave)}: variable '{output}' (output) cannot be set in state Instantiated"
    slave.fmu.reset()
    slave.initialize()
    assert status_of(lambda: slave.set_real([0], [1.0])) == ERROR
    assert slave.last_error() == f"{set_name(slave)}: variable 'time' (independent) cannot be set in state StepMode"


@pytest.mark.parametrize("which", ["next", "large", "max"])
def test_unknown_value_reference_is_rejected(slave: Slave, which: str) -> None:
    slave.initialize()
    n = max(slave.vr.values())  # value references 0 (time) .. n
    model = model_of(slave.path)
    elements = sum(v.size for v in model.variables if v.shape) if slave.fmi_version == 2 else 0
    assert n == len(model.variables) + elements  # FMI 2: array elements numbered after the variables
    vr = {"next": n + 1, "large": 999, "max": 2**32 - 1}[which]
    assert status_of(lambda: slave.get_real([vr])) == ERROR
    assert slave.last_error() == (f"{get_name(slave)}: unknown value reference {vr} ({slave.identifier} has "
                                  f"value references 0..{n})")
    slave.fmu.reset()
    real = CASES[slave.identifier]["real_input"]
    assert status_of(lambda: slave.set_real([slave.vr[real], vr], [0.0, 0.0])) == ERROR
    assert f"unknown value reference {vr}" in slave.last_error()


def test_an_fmi3_array_is_not_a_value_reference_in_fmi2() -> None:
    """FMI 2 has one scalar per element of an FMI 3 array; the array's own value reference is unused."""
    for model in MODELS.values():
        for v in (v for v in model.variables if v.shape):
            with Slave(require_fmu(fmu_dir() / f"{model.identifier}_fmi2.fmu")) as slave:
                slave.instantiate()
                slave.initialize()
                vr = model.variables.index(v) + 1
                assert vr not in slave.vr.values()
                assert status_of(lambda: slave.get_real([vr])) == ERROR
                assert slave.last_error() == (f"fmi2GetReal: unknown value reference {vr}: it is an array in the FMI 3 "
                                              f"variant of {model.identifier}; FMI 2 has one variable per element")
                assert len(slave.get([v.name])) == v.size


def test_wrong_type_for_a_value_reference_is_rejected(slave: Slave) -> None:
    case = CASES[slave.identifier]
    real, boolean = case["real_input"], case["boolean_input"]
    slave.initialize()
    assert status_of(lambda: slave.fmu.getBoolean([slave.vr[real]])) == ERROR
    assert slave.last_error() == (f"{slave.prefix}GetBoolean: variable '{real}' (value reference "
                                  f"{slave.vr[real]}) is Float64, not Boolean")
    slave.fmu.reset()
    if boolean:
        assert status_of(lambda: slave.set_real([slave.vr[boolean]], [1.0])) == ERROR
        assert slave.last_error() == (f"{set_name(slave)}: variable '{boolean}' (value reference "
                                      f"{slave.vr[boolean]}) is Boolean, not Float64")
        slave.fmu.reset()
    integer = "Integer" if slave.fmi_version == 2 else "Int32"
    setter = getattr(slave.fmu, f"set{integer}")
    assert status_of(lambda: setter([slave.vr[real]], [1])) == ERROR
    assert slave.last_error() == (f"{slave.prefix}Set{integer}: variable '{real}' (value reference "
                                  f"{slave.vr[real]}) is Float64, not Int32")
    slave.fmu.reset()
    assert status_of(lambda: slave.fmu.setString([slave.vr[real]], ["x"])) == ERROR
    assert slave.last_error() == (f"{slave.prefix}SetString: variable '{real}' (value reference "
                                  f"{slave.vr[real]}) is Float64, not String")
    slave.fmu.reset()
    assert status_of(lambda: slave.fmu.setFloat32([slave.vr[real]], [1.0]) if slave.fmi_version == 3
                     else slave.fmu.setString([slave.vr[real]], ["x"])) == ERROR


@pytest.mark.parametrize("fmu3", FMI3_FMUS, ids=fmu_id)
def test_fmi3_value_count_must_match_the_value_references(fmu3: Path) -> None:
    with Slave(require_fmu(fmu3)) as slave:
        a, b = [v.valueReference for v in slave.md.modelVariables
                if v.type == "Float64" and v.causality in ("parameter", "input") and not v.dimensions][:2]
        slave.instantiate()
        slave.initialize()
        assert status_of(lambda: slave.get_real([a, b], n_values=3)) == ERROR
        assert slave.last_error() == ("fmi3GetFloat64: nValues = 3 but the 2 value references stand for 2 values "
                                      "(arrays count all their elements)")
        slave.fmu.reset()
        slave.initialize()
        vrs = (fmi3ValueReference * 2)(a, b)
        values = (fmi3Float64 * 1)(0.1)
        assert status_of(lambda: slave.fmu.fmi3SetFloat64(slave.fmu.component, vrs, 2, values, 1)) == ERROR
        assert "fmi3SetFloat64: nValues = 1 but the 2 value references stand for 2 values" in slave.last_error()
        for v in (v for v in slave.md.modelVariables if v.dimensions):  # an array counts all its elements
            size = slave.sizes[v.name]
            assert len(slave.get_real([v.valueReference], n_values=size)) == size
            assert status_of(lambda: slave.get_real([v.valueReference, a], n_values=size)) == ERROR
            assert f"stand for {size + 1} values" in slave.last_error()
            slave.fmu.reset()
            slave.initialize()
        slave.fmu.reset()
        slave.initialize()
        assert status_of(lambda: slave.fmu.fmi3GetFloat64(slave.fmu.component, None, 1, values, 1)) == ERROR
        assert slave.last_error() == "fmi3GetFloat64: valueReferences is NULL but nValueReferences = 1"


@pytest.mark.parametrize("wrong", ["{00000000-0000-0000-0000-000000000000}", "", "%s%n#1#%"],
                         ids=["zeros", "empty", "printf"])
def test_wrong_instantiation_token_is_refused(fmu: Path, wrong: str) -> None:
    """The token is echoed in the message: in FMI 2 its '%' and '#' must arrive escaped (checked by the
    test logger), or the importer's printf would read arguments that were never passed."""
    model = model_of(fmu)
    with Slave(fmu, guid=wrong) as slave:
        with pytest.raises(Exception, match="Failed to instantiate"):
            slave.instantiate()
        assert slave.fmu.component is None
        function = "fmi2Instantiate" if slave.fmi_version == 2 else "fmi3InstantiateCoSimulation"
        assert slave.last_error() == (f"{function}: wrong instantiation token/GUID '{wrong}'; this FMU "
                                      f"({model.identifier}) has '{model.instantiation_token()}': the model "
                                      "description and the binary do not belong together")


# ---- the error state ----


def test_after_an_error_only_reset_free_get_and_state_calls_work(slave: Slave) -> None:
    model = model_of(slave.path)
    p = slave.prefix
    name = CASES[slave.identifier]["real_input"]
    points = random_points(slave.path, 6, seed=9)
    slave.initialize(points[0])
    run_points(slave, points[:2])
    assert status_of(lambda: slave.set({name: math.nan})) == ERROR
    n_errors = len(slave.errors())

    assert slave.step(1e-3) == ERROR
    assert slave.last_error() == f"{p}DoStep: illegal call sequence: not allowed in state Error"
    assert status_of(lambda: slave.set({name: 0.0})) == ERROR
    assert slave.last_error() == f"{set_name(slave)}: illegal call sequence: not allowed in state Error"
    assert status_of(lambda: slave.fmu.terminate()) == ERROR
    assert slave.last_error() == f"{p}Terminate: illegal call sequence: not allowed in state Error"
    assert status_of(lambda: slave.fmu.exitInitializationMode()) == ERROR
    assert slave.last_error() == f"{p}ExitInitializationMode: illegal call sequence: not allowed in state Error"
    assert len(slave.errors()) == n_errors + 4

    # get and FMU state calls still work: the outputs of the last good step
    assert_close(slave.get(output_names(model)), reference_trajectory(model, points[:2], 1e-3)[-1])
    state = slave.fmu.getFMUState()
    slave.fmu.freeFMUState(state)
    assert len(slave.errors()) == n_errors + 4

    assert slave.fmu.reset() == OK
    slave.initialize(points[2])
    actual = run_points(slave, points[2:])
    assert_close(actual, reference_trajectory(model, points[2:], 1e-3))
    assert slave.get(["time"])[0] == pytest.approx(4e-3)
    assert len(slave.errors()) == n_errors + 4


def test_an_fmu_state_from_before_an_error_restores_the_instance(slave: Slave) -> None:
    """FMI 2.0 4.2.4 / FMI 3.0: after Error, setting a previously retrieved FMU state is the alternative to reset."""
    model = model_of(slave.path)
    points = random_points(slave.path, 8, seed=12)
    slave.initialize(points[0])
    run_points(slave, points[:3])
    state = slave.fmu.getFMUState()
    reference = run_points(slave, points[3:])
    slave.set_state(state)
    assert slave.step(-1.0) == ERROR
    assert slave.step(1e-3) == ERROR and "not allowed in state Error" in slave.last_error()
    slave.set_state(state)
    assert np.array_equal(run_points(slave, points[3:]), reference)
    assert_close(reference, reference_trajectory(model, points, 1e-3)[3:])
    slave.fmu.freeFMUState(state)


def test_reset_restores_start_values(slave: Slave) -> None:
    model = model_of(slave.path)
    points = random_points(slave.path, 3, seed=4)
    slave.initialize(points[2])
    run_points(slave, points[2:])
    slave.fmu.reset()
    slave.initialize()
    assert slave.get(["time"])[0] == 0.0
    names = [v.name for v in model.of("parameter") + model.of("input") if v.type == "Float64"]
    assert_close(slave.get(names), [model.variable(n).start for n in names for _ in range(model.variable(n).size)])
    assert_close(slave.get(output_names(model)), expected_outputs(model, {})[0])


# ---- FMU state ----


def _power_points_with_a_warning(fmu: Path, count: int) -> list[dict]:
    points = random_points(fmu, count, seed=21)
    if split_fmu_name(fmu)[0] == "SpindlePower":
        for point in points:
            point["spindle_on"] = 1.0
        points[count - 3].update(spindle_on=0.0, mrr=2e-6)  # after the snapshot: warns (once) again
    return points


def test_get_and_set_fmu_state_rolls_back_bit_identically(fmu: Path) -> None:
    points = _power_points_with_a_warning(fmu, 12)
    with Slave(fmu, "fresh") as fresh:
        fresh.instantiate()
        fresh.initialize(points[0])
        reference = run_points(fresh, points)

    with Slave(fmu, "rolled back") as slave:
        slave.instantiate()
        slave.initialize(points[0])
        first = run_points(slave, points[:6])
        state = slave.fmu.getFMUState()
        rest = run_points(slave, points[6:])
        warnings = len(slave.warnings())
        for attempt in range(3):
            slave.set_state(state)
            assert slave.get(["time"])[0] == pytest.approx(6e-3)
            again = run_points(slave, points[6:])
            assert np.array_equal(again, rest), f"attempt {attempt}"
        assert len(slave.warnings()) == 4 * warnings  # the warned-once flag is part of the state
        slave.fmu.freeFMUState(state)
        assert not slave.errors()
    assert np.array_equal(np.vstack([first, rest]), reference)


def test_fmu_state_is_overwritten_in_place_when_reused(fmu: Path) -> None:
    points = random_points(fmu, 4, seed=5)
    with Slave(fmu) as slave:
        slave.instantiate()
        slave.initialize(points[0])
        state = slave.fmu.getFMUState()
        run_points(slave, points[:2])
        address = state.value
        getattr(slave.fmu, f"{slave.prefix}Get{'FMUstate' if slave.fmi_version == 2 else 'FMUState'}")(
            slave.fmu.component, ctypes.byref(state))
        assert state.value == address
        after_two = run_points(slave, points[2:])
        slave.set_state(state)
        assert slave.get(["time"])[0] == pytest.approx(2e-3)
        assert np.array_equal(run_points(slave, points[2:]), after_two)
        slave.fmu.freeFMUState(state)
        assert not state


def test_serialized_fmu_state_round_trip(fmu: Path) -> None:
    points = _power_points_with_a_warning(fmu, 10)
    with Slave(fmu, "first") as first, Slave(fmu, "second") as second:
        first.instantiate()
        first.initialize(points[0])
        run_points(first, points[:5])
        state = first.fmu.getFMUState()
        data = first.fmu.serializeFMUState(state)
        first.fmu.freeFMUState(state)
        assert isinstance(data, bytes) and len(data) > 0
        reference = run_points(first, points[5:])

        restored = first.fmu.deserializeFMUState(data)
        assert first.fmu.serializeFMUState(restored) == data
        first.set_state(restored)
        first.fmu.freeFMUState(restored)
        assert np.array_equal(run_points(first, points[5:]), reference)

        second.instantiate()  # a fresh instance continues from the other one's state
        state = second.fmu.deserializeFMUState(data)
        second.set_state(state)
        second.fmu.freeFMUState(state)
        assert second.get(["time"])[0] == pytest.approx(5e-3)
        assert np.array_equal(run_points(second, points[5:]), reference)
        assert not first.errors() and not second.errors()


def test_corrupt_serialized_state_is_rejected(fmu: Path) -> None:
    with Slave(fmu) as slave:
        slave.instantiate()
        slave.initialize()
        state = slave.fmu.getFMUState()
        data = slave.fmu.serializeFMUState(state)
        slave.fmu.freeFMUState(state)
        p = slave.prefix
        function = f"{p}DeSerializeFMUstate" if slave.fmi_version == 2 else "fmi3DeserializeFMUState"
        assert status_of(lambda: slave.fmu.deserializeFMUState(data[:-1])) == ERROR
        if keeps_heap_data(model_of(fmu)):  # the header is complete: the size it states is checked
            assert slave.last_error() == (f"{function}: serialized FMUstate has {len(data) - 1} bytes, expected "
                                          f"{len(data)}")
        else:  # no heap data: the whole state is the fixed-size header
            assert slave.last_error() == (f"{function}: serialized FMUstate has {len(data) - 1} bytes, at least "
                                          f"{len(data)} expected (or a NULL pointer was passed)")
        slave.fmu.reset()
        assert status_of(lambda: slave.fmu.deserializeFMUState(data + b"\0")) == ERROR
        assert slave.last_error() == (f"{function}: serialized FMUstate has {len(data) + 1} bytes, expected "
                                      f"{len(data)}")
        slave.fmu.reset()
        assert status_of(lambda: slave.fmu.deserializeFMUState(bytes(len(data)))) == ERROR
        assert slave.last_error().startswith(f"{function}: FMUstate was not made by this FMU ({slave.identifier}")


def test_two_instances_stepped_interleaved_equal_each_alone(fmu: Path) -> None:
    a_points = random_points(fmu, 15, seed=31)
    b_points = random_points(fmu, 15, seed=32)
    alone, warnings = {}, {}
    for name, points in (("a", a_points), ("b", b_points)):
        with Slave(fmu, name) as slave:
            slave.instantiate()
            slave.initialize(points[0])
            alone[name] = run_points(slave, points, step_size=1e-3 if name == "a" else 2e-3)
            warnings[name] = slave.warnings()
    with Slave(fmu, "a") as a, Slave(fmu, "b") as b:
        a.instantiate()
        b.instantiate()
        a.initialize(a_points[0])
        b.initialize(b_points[0])
        rows = {"a": [], "b": []}
        for pa, pb in zip(a_points, b_points):
            a.set(pa, include_fixed=False)  # both set before either steps: a shared global would mix them
            b.set(pb, include_fixed=False)
            assert a.step(1e-3) in (OK, WARNING)
            assert b.step(2e-3) in (OK, WARNING)
            rows["a"].append(a.get(output_names(model_of(fmu))))
            rows["b"].append(b.get(output_names(model_of(fmu))))
        assert b.get(["time"])[0] == pytest.approx(2 * a.get(["time"])[0])
        assert np.array_equal(np.array(rows["a"]), alone["a"])
        assert np.array_equal(np.array(rows["b"]), alone["b"])
        assert len(a.warnings()) == len(warnings["a"]) and len(b.warnings()) == len(warnings["b"])
        if a.identifier == "SpindlePower":  # each instance warns once for itself
            assert len(warnings["a"]) == len(warnings["b"]) == 1
        assert status_of(lambda: a.set({CASES[a.identifier]["real_input"]: math.nan})) == ERROR
        assert b.step(2e-3) in (OK, WARNING)  # an error of one instance leaves the other alone
        assert not b.errors()


# ---- SpindlePower's own check ----


@pytest.fixture(params=POWER_FMUS, ids=fmu_id)
def power(request):
    with Slave(require_fmu(request.param)) as s:
        s.instantiate()
        yield s


def test_power_warns_once_when_material_is_removed_with_the_spindle_off(power: Slave) -> None:
    power.initialize({"spindle_on": True, "mrr": 1e-6, "spindle_speed": 100.0})
    assert power.step(1e-3) == OK
    power.set({"spindle_on": False})
    assert power.step(1e-3) == WARNING
    assert len(power.messages) == 1
    message = power.messages[0]
    assert message.status == WARNING and message.category == "logStatusWarning"
    assert "t = 0.001 s: input 'mrr' = 1e-06 m3/s > 0 while 'spindle_on' is false" in message.message
    assert "reported once" in message.message
    assert_close(power.get(["P_total", "P_spindle", "P_cutting"]), [500.0, 0.0, 0.0])
    for _ in range(5):
        assert power.step(1e-3) == OK
    assert len(power.messages) == 1
    power.fmu.reset()  # a new run warns again
    power.initialize({"spindle_on": False, "mrr": 2e-6})
    assert power.step(1e-3) == WARNING
    assert len(power.warnings()) == 2 and not power.errors()


def test_power_does_not_warn_without_material_removal(power: Slave) -> None:
    power.initialize({"spindle_on": False, "mrr": 0.0, "spindle_speed": 50.0})
    for _ in range(3):
        assert power.step(1e-3) == OK
    power.set({"spindle_on": True, "mrr": 3e-6})
    assert power.step(1e-3) == OK
    assert power.messages == []


# ---- logging ----


def test_events_are_logged_only_with_debug_logging_on(fmu: Path) -> None:
    boolean = CASES[split_fmu_name(fmu)[0]]["boolean_input"]
    point = {**random_points(fmu, 3, seed=2)[2], **({boolean: 1.0} if boolean else {})}
    with Slave(fmu, "quiet") as quiet, Slave(fmu, "verbose") as verbose:
        for slave, logging_on in ((quiet, False), (verbose, True)):
            slave.instantiate(logging_on=logging_on)
            slave.initialize(point)
            run_points(slave, [point])
            slave.fmu.terminate()
        assert quiet.messages == []
        events = [m for m in verbose.messages if m.status == OK]
        # ForceNet also names, at instantiation, the network kernel its CPU picks (AVX2 or baseline)
        kernel = [m for m in events if ": network kernel " in m.message]
        assert len(kernel) == (verbose.identifier == "ForceNet"), kernel
        events = [m for m in events if m not in kernel]
        assert [m.category for m in events] == ["logEvents"] * 3
        p = verbose.prefix
        instantiate = "fmi2Instantiate" if p == "fmi2" else "fmi3InstantiateCoSimulation"
        assert events[0].message == f"{instantiate}: instance 'verbose' of {verbose.identifier} created"
        assert events[1].message == f"{p}ExitInitializationMode: initialized at t = 0 s"
        assert events[2].message == f"{p}Terminate: terminated at t = 0.001 s"
        verbose.fmu.reset()
        verbose.fmu.setDebugLogging(True, ["logStatusError"])  # events off, errors still reported
        verbose.messages.clear()
        verbose.initialize()
        assert verbose.messages == []
        assert verbose.step(0.0) == ERROR and len(verbose.errors()) == 1


# ---- the bad-input matrix (docs/testing.md "Bad input: what you get"): zero, negative and huge values, huge steps,
# call order, missing resources ----


def _ranged(model) -> list:
    """Scalar parameters and inputs with a range (min and max in the model description)."""
    return [v for v in model.of("parameter") + model.of("input")
            if v.type != "Boolean" and not v.shape and v.min is not None and v.max is not None]


def _range_message(slave: Slave, v, value: float) -> str:
    unit = f" {v.unit}" if v.unit else ""
    return (f"{set_name(slave, v.name)}: variable '{v.name}' = {c_number(value)}{unit} is out of its allowed range "
            f"[{c_number(v.min)}, {c_number(v.max)}]{unit}")


def test_zero_or_negative_where_positive_is_required_is_rejected(fmu: Path) -> None:
    """Every variable whose minimum is above zero (periods, feeds, stiffnesses, diameters, counts, ...) rejects
    0 and a negative value, naming the variable, the value and the range. MrrEstimator has none: a zero width
    or depth of cut is a valid "no cut"."""
    model = model_of(fmu)
    positive = [v for v in _ranged(model) if v.min > 0]
    assert positive or model.identifier == "MrrEstimator"
    with Slave(fmu) as slave:
        slave.instantiate()
        for v in positive:
            for value in (0.0, -1.0 if v.type == "Int32" else -v.min):
                assert status_of(lambda: slave.set({v.name: value})) == ERROR, v.name
                assert slave.last_error() == _range_message(slave, v, value)
                slave.fmu.reset()
        slave.initialize()  # nothing rejected was applied
        assert slave.step(1e-3) in (OK, WARNING)


def test_huge_values_are_rejected_with_their_range(fmu: Path) -> None:
    """1e300 (Float64) or 2^31 - 1 (Int32) and their negatives, for every ranged parameter and input."""
    model = model_of(fmu)
    with Slave(fmu) as slave:
        slave.instantiate()
        for v in _ranged(model):
            huge = 2.0**31 - 1 if v.type == "Int32" else 1e300
            for value in (huge, -huge if v.type != "Int32" else -(2.0**31)):
                assert status_of(lambda: slave.set({v.name: value})) == ERROR, v.name
                assert slave.last_error() == _range_message(slave, v, value)
                slave.fmu.reset()


@pytest.mark.parametrize("values", ["start", "max"])
def test_a_huge_step_returns_at_once_with_finite_outputs(fmu: Path, values: str) -> None:
    """doStep over 1e9 s (start values, or every parameter and input at its maximum): it returns within a
    second, with finite outputs, and the next step works."""
    model = model_of(fmu)
    point = {} if values == "start" else {v.name: v.max for v in _ranged(model)}
    with Slave(fmu) as slave:
        slave.instantiate()
        slave.initialize(point)
        start = time.perf_counter()
        assert slave.step(1e9) in (OK, WARNING), slave.messages
        assert time.perf_counter() - start < 1.0
        assert np.all(np.isfinite(slave.get(output_names(model))))
        assert slave.step(1e-3) in (OK, WARNING)
        assert not slave.errors()


@pytest.mark.parametrize("version", [3, 2])
def test_interpolator_step_after_the_program_end_equals_small_steps(version: int) -> None:
    """The Interpolator skips the ticks after its program's end: one 60 s step gives the outputs of 60,000
    steps of 1 ms, and a 1e9 s step (1e12 periods) returns at once."""
    path = require_fmu(fmu_dir() / ("Interpolator.fmu" if version == 3 else "Interpolator_fmi2.fmu"))
    names = output_names(model_of(path))
    rows = []
    for steps in ([60.0], [1e-3] * 60_000):
        with Slave(path) as slave:
            slave.instantiate()
            slave.initialize()
            for h in steps:
                assert slave.step(h) == OK
            assert slave.get(["finished"])[0] == 1.0  # the default program ends before 60 s
            rows.append(slave.get(names))
            start = time.perf_counter()
            assert slave.step(1e9) == OK
            assert time.perf_counter() - start < 0.1
            assert np.array_equal(slave.get(names), rows[-1])  # at rest at the program's end
    assert np.array_equal(rows[0], rows[1])



@pytest.mark.parametrize("version", [3, 2])
def test_interpolator_step_in_a_feed_hold_equals_small_steps(version: int) -> None:
    """Feed hold (feed_override = 0) in the middle of the program: once the tool stands still the Interpolator
    skips the ticks, so a 60 s step gives what 60,000 steps of 1 ms give, a 1e9 s step returns at once, and
    after the hold is released both continue identically."""
    path = require_fmu(fmu_dir() / ("Interpolator.fmu" if version == 3 else "Interpolator_fmi2.fmu"))
    names = output_names(model_of(path))
    runs = []
    for steps in ([60.0], [1e-3] * 60_000):
        with Slave(path) as slave:
            slave.instantiate()
            slave.initialize()
            assert slave.step(0.5) == OK
            slave.set({"feed_override": 0.0})
            for h in steps:
                assert slave.step(h) == OK
            held = slave.get(names)
            assert slave.get(["feed", "finished"]).tolist() == [0.0, 0.0]  # stopped mid-program
            start = time.perf_counter()
            assert slave.step(1e9) == OK
            assert time.perf_counter() - start < 0.1
            assert np.array_equal(slave.get(names), held)
            slave.set({"feed_override": 1.0})
            for _ in range(2000):
                assert slave.step(1e-3) == OK
            runs.append((held, slave.get(names)))
    assert np.array_equal(runs[0][0], runs[1][0]) and np.array_equal(runs[0][1], runs[1][1])
    assert not np.array_equal(runs[0][0], runs[0][1])  # it moved again after the hold

def test_wrong_call_order_is_an_illegal_call_sequence(slave: Slave) -> None:
    p = slave.prefix
    expected = "{}: illegal call sequence: not allowed in state {}"
    assert status_of(lambda: slave.fmu.exitInitializationMode()) == ERROR
    assert slave.last_error() == expected.format(f"{p}ExitInitializationMode", "Instantiated")
    slave.fmu.reset()
    assert status_of(lambda: slave.fmu.terminate()) == ERROR
    assert slave.last_error() == expected.format(f"{p}Terminate", "Instantiated")
    slave.fmu.reset()
    slave.enter_initialization()
    assert status_of(lambda: slave.enter_initialization()) == ERROR
    first = f"{p}SetupExperiment" if slave.fmi_version == 2 else "fmi3EnterInitializationMode"
    assert slave.last_error() == expected.format(first, "InitializationMode")
    slave.fmu.reset()
    slave.initialize()
    if slave.fmi_version == 2:
        assert status_of(lambda: slave.fmu.setupExperiment(startTime=0.0)) == ERROR
        assert slave.last_error() == expected.format("fmi2SetupExperiment", "StepMode")
        slave.fmu.reset()
        slave.initialize()
    assert slave.step(1e-3) == OK
    slave.fmu.terminate()
    assert slave.step(1e-3) == ERROR
    assert slave.last_error() == expected.format(f"{p}DoStep", "Terminated")
    slave.fmu.reset()
    slave.initialize()
    slave.fmu.terminate()
    assert status_of(lambda: slave.fmu.terminate()) == ERROR
    assert slave.last_error() == expected.format(f"{p}Terminate", "Terminated")
    assert slave.fmu.reset() == OK  # and the instance is usable again
    slave.initialize()
    assert slave.step(1e-3) in (OK, WARNING)


RESOURCE_FILES = {"Interpolator": "program.nc", "ForceNet": "weights.bin"}


def test_a_missing_resources_folder_is_reported(fmu: Path, tmp_path: Path) -> None:
    """The FMU unpacked without its resources/ folder (the importer still passes the location): the FMUs that
    read a resource fail, naming the file they looked for; the others do not need one and run."""
    identifier, version = split_fmu_name(fmu)
    folder = tmp_path / "unpacked"
    with zipfile.ZipFile(fmu) as archive:
        archive.extractall(folder)
    shutil.rmtree(folder / "resources", ignore_errors=True)
    file = folder / "resources" / RESOURCE_FILES.get(identifier, "")
    with Slave(fmu, unzipdir=str(folder)) as slave:
        if identifier == "ForceNet":
            with pytest.raises(Exception, match="Failed to instantiate"):
                slave.instantiate()
            function = "fmi3InstantiateCoSimulation" if version == 3 else "fmi2Instantiate"
            assert slave.last_error() == (f"{function}: the force-net weights file cannot be read: cannot open "
                                          f"'{file}': No such file or directory (the FMU's resources/ must hold "
                                          "weights.bin, format in models/force_net.py)")
            return
        slave.instantiate()
        slave.enter_initialization()
        if identifier == "Interpolator":
            assert status_of(lambda: slave.exit_initialization()) == ERROR
            assert slave.last_error() == (f"exitInitializationMode: parameter 'program' is empty and cannot open "
                                          f"part program '{file}': No such file or directory")
            return
        slave.exit_initialization()
        assert slave.step(1e-3) in (OK, WARNING) and not slave.errors()


def test_a_fixed_parameter_cannot_be_set_after_initialization(fmu: Path) -> None:
    """Fixed parameters (sizes, counts, periods) are rejected after initialization, naming the variable; the
    tunable ones of every FMU are accepted and take effect at the next step."""
    model = model_of(fmu)
    fixed = [v for v in _ranged(model) if v.causality == "parameter" and v.variability == "fixed"]
    tunable = [v for v in _ranged(model) if v.causality == "parameter" and v.variability != "fixed"]
    with Slave(fmu) as slave:
        slave.instantiate()
        slave.initialize()
        for v in fixed:
            assert status_of(lambda: slave.set({v.name: v.start})) == ERROR, v.name
            assert slave.last_error() == (f"{set_name(slave, v.name)}: variable '{v.name}' (parameter) cannot be set "
                                          "in state StepMode")
            slave.fmu.reset()
            slave.initialize()
        for v in tunable:
            slave.set({v.name: v.max})
            assert slave.get([v.name])[0] == v.max
        status = slave.step(1e-3)
        if model.identifier == "Workpiece":  # its largest tool (0.1 m) is a tool change the default stock rejects
            assert status == ERROR and "tool change: the tool is larger than the stock" in slave.last_error()
            return
        assert status in (OK, WARNING) and len(slave.errors()) == len(fixed)


# ---- array inputs (FMI 3: one variable with dimensions, FMI 2: one scalar per element) ----

ARRAY_INPUTS = [(p, v.name) for p in FMUS for v in model_of(p).variables if v.shape and v.causality != "output"]


def _array_setter(slave: Slave, name: str) -> tuple[str, Callable[[np.ndarray], None]]:
    """(the FMI function's name, a call setting the whole array) in either version."""
    if slave.fmi_version == 3:
        return "fmi3SetFloat64", lambda values: slave.set_real([slave.vr[name]], list(values))
    return "fmi2SetReal", lambda values: slave.set_real(slave.elements[name], list(values))


def _element(v, flat: int) -> str:
    return v.element_names()[flat]


@pytest.mark.parametrize("fmu, name", ARRAY_INPUTS, ids=[f"{fmu_id(p)}-{n}" for p, n in ARRAY_INPUTS])
@pytest.mark.parametrize("bad", [math.nan, math.inf, "above", "below"])
def test_array_input_elements_are_checked_one_by_one(fmu: Path, name: str, bad) -> None:
    """A NaN, Inf or out-of-range element is rejected with a message naming the element (1-based, as the FMI 2
    variant names it), and the array keeps its values (FMI 3: no element of the rejected call is stored)."""
    v = model_of(fmu).variable(name)
    flat = v.size // 3 + 5  # some element inside, not the first
    value = {"above": v.max + 1.0, "below": v.min - 0.5}.get(bad, bad)
    with Slave(require_fmu(fmu)) as slave:
        slave.instantiate()
        slave.initialize()
        function, set_all = _array_setter(slave, name)
        good = np.linspace(v.min, v.max, v.size)
        set_all(good)
        values = good.copy()
        values[flat] = value
        assert status_of(lambda: set_all(values)) == ERROR
        unit = f" {v.unit}" if v.unit else ""
        if isinstance(bad, str):
            expected = (f"{function}: variable '{_element(v, flat)}' = {c_number(value)}{unit} is out of its allowed "
                        f"range [{c_number(v.min)}, {c_number(v.max)}]{unit}")
        else:
            expected = f"{function}: variable '{_element(v, flat)}' set to {value}: must be a finite number"
        assert slave.last_error() == expected
        if slave.fmi_version == 3:  # checked before any element is stored
            assert np.array_equal(slave.get([name]), good)
        else:  # one scalar per element: those before the bad one were set, the bad one not
            assert np.array_equal(slave.get([name])[flat:], good[flat:])


@pytest.mark.parametrize("fmu, name", ARRAY_INPUTS, ids=[f"{fmu_id(p)}-{n}" for p, n in ARRAY_INPUTS])
def test_array_input_round_trips_and_is_part_of_fmu_states(fmu: Path, name: str) -> None:
    v = model_of(fmu).variable(name)
    rng = np.random.default_rng(9)
    first, second = (rng.uniform(v.min, v.max, v.size) for _ in range(2))
    with Slave(require_fmu(fmu), "first") as slave, Slave(fmu, "second") as other:
        slave.instantiate()
        slave.initialize()
        assert np.array_equal(slave.get([name]), np.full(v.size, v.start))  # the start value in every element
        _, set_all = _array_setter(slave, name)
        set_all(first)
        assert np.array_equal(slave.get([name]), first)
        if slave.fmi_version == 3:  # one value reference, nValues counts the elements
            assert status_of(lambda: slave.fmu.fmi3SetFloat64(
                slave.fmu.component, (fmi3ValueReference * 1)(slave.vr[name]), 1,
                (fmi3Float64 * (v.size - 1))(*first[1:]), v.size - 1)) == ERROR
            assert slave.last_error() == (f"fmi3SetFloat64: nValues = {v.size - 1} but the 1 value references "
                                          f"stand for {v.size} values (arrays count all their elements)")
            slave.fmu.reset()
            slave.initialize()
            set_all(first)
        state = slave.fmu.getFMUState()
        set_all(second)
        assert np.array_equal(slave.get([name]), second)
        slave.set_state(state)
        assert np.array_equal(slave.get([name]), first)
        data = slave.fmu.serializeFMUState(state)
        slave.fmu.freeFMUState(state)
        other.instantiate()
        restored = other.fmu.deserializeFMUState(data)
        other.set_state(restored)
        other.fmu.freeFMUState(restored)
        assert np.array_equal(other.get([name]), first)
        assert len(slave.errors()) == (1 if slave.fmi_version == 3 else 0) and not other.errors()
