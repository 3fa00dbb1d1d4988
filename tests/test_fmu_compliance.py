"""Every built FMU (FMI 3.0 and FMI 2.0): standard-conformant, computes exactly the model of models/,
exports only FMI symbols, runs in an independent master (libcosim) and rebuilds from its sources."""
from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import fmpy
import numpy as np
import pytest
from fmpy.build import build_platform_binary
from fmpy.util import create_zip_archive
from fmpy.validation import validate_fmu

from fmu_helpers import (
    OK,
    WARNING,
    Slave,
    all_fmus,
    assert_close,
    expected_fmus,
    expected_outputs,
    numeric_parameters,
    points_of,
    reference_trajectory,
    fmu_dir,
    fmu_id,
    model_of,
    output_names,
    random_arguments,
    require_fmu,
    row,
    scalar_inputs,
    simulate_points,
    split_fmu_name,
)

FMUS = all_fmus()
FMI2_FMUS = [p for p in FMUS if split_fmu_name(p)[1] == 2]


@pytest.fixture(params=FMUS, ids=fmu_id)
def fmu(request) -> Path:
    return require_fmu(request.param)


@pytest.fixture(params=FMI2_FMUS, ids=fmu_id)
def fmu2(request) -> Path:
    return require_fmu(request.param)


def test_every_model_was_built_in_both_fmi_versions() -> None:
    folder = fmu_dir()
    assert folder.is_dir() and any(folder.glob("*.fmu")), f"no FMUs in {folder}: build first"
    missing = [p.name for p in expected_fmus() if not p.is_file()]
    assert not missing, f"not built: {missing}"


def test_model_description_matches_the_model_definition(fmu: Path) -> None:
    model = model_of(fmu)
    identifier, version = split_fmu_name(fmu)
    md = fmpy.read_model_description(str(fmu))
    assert md.fmiVersion == f"{version}.0"
    assert md.coSimulation is not None and md.modelExchange is None
    assert md.coSimulation.modelIdentifier == identifier
    assert md.guid == model.instantiation_token()
    described = {v.name: v for v in md.modelVariables}
    # an array is one variable with dimensions in FMI 3, one scalar per element in FMI 2
    names = [[v.name] if not v.shape or version == 3 else v.element_names() for v in model.variables]
    assert set(described) == {"time"} | {name for group in names for name in group}
    for v in model.variables:
        if v.shape:
            if version == 3:
                assert [int(d.start) for d in described[v.name].dimensions] == list(v.shape), v.name
            else:
                assert described[f"{v.name}[{','.join(map(str, v.shape))}]"].causality == v.causality
            continue
        d = described[v.name]
        assert d.causality == v.causality, v.name
        if v.min is not None:
            assert float(d.min) == v.min and float(d.max) == v.max, v.name
        if v.start is not None and v.type == "String":
            assert (d.start or "") == v.start, v.name
        elif v.start is not None and v.type != "Boolean":
            assert float(d.start) == v.start, v.name


def test_validate_fmu_finds_no_problems(fmu: Path) -> None:
    assert validate_fmu(str(fmu)) == []


def test_simulate_fmu_gives_the_model_outputs(fmu: Path) -> None:
    """fmpy's own master: parameters as start values, inputs as a (constant) input signal."""
    model = model_of(fmu)
    rng = np.random.default_rng(7)
    values = random_arguments(model, 8, rng)
    inputs = scalar_inputs(model)
    for i in range(2, 5):  # random (not corner) points
        point = row(values, i)
        parameters = {v.name: point[v.name] for v in numeric_parameters(model)}
        dtype = [("time", float)] + [(v.name, bool if v.type == "Boolean" else float) for v in inputs]
        signal = np.array([(0.0, *(point[v.name] for v in inputs)), (0.1, *(point[v.name] for v in inputs))],
                          dtype=dtype)
        version = split_fmu_name(fmu)[1]
        names = [n for v in model.of("output") for n in (v.element_names() if v.shape and version == 2 else [v.name])]
        result = fmpy.simulate_fmu(str(fmu), stop_time=0.05, output_interval=1e-3, start_values=parameters,
                                   input=signal, output=names, validate=True, logger=lambda *args: None)
        assert len(result) == 51
        assert result["time"][-1] == pytest.approx(0.05)
        expected = np.vstack([expected_outputs(model, point), reference_trajectory(model, [point] * 50, 1e-3)])
        actual = np.column_stack([np.reshape(result[n], (len(result), -1)) for n in names])  # arrays row-major
        assert_close(actual, expected, what=f"outputs at point {point}")
        if model.identifier == "SpindlePower" and point["spindle_on"] and point["mrr"] > 0:
            assert result["P_cutting"][0] > 0  # the random point exercises the cutting term


POWER_FMUS = [p for p in FMUS if split_fmu_name(p)[0] == "SpindlePower"]


def spindle_run_up(step_size: float) -> list[dict[str, float]]:
    """SpindlePower's inputs over a run-up like UMich run 01's: stopped, M3 with the command at 53.3 rev/s, the
    speed ramping at 100 rev/s2, held (with a speed error), then M5 and the speed falling at 100 rev/s2."""
    omega = 2 * np.pi  # rad/s per rev/s
    slope = 100.0 * omega * step_size  # rad/s per step
    command = 53.3 * omega
    speeds = ([0.0] * 3 + [slope * k for k in range(1, 54)] + [command - 0.5, command + 0.3] * 5
              + [command - slope * k for k in range(1, 11)])
    on = [0.0] * 3 + [1.0] * (53 + 10) + [0.0] * 10
    commands = [0.0] * 3 + [command] * (53 + 10) + [0.0] * 10
    return [{"spindle_speed": n, "spindle_on": s, "spindle_speed_command": c, "mrr": 0.0}
            for n, s, c in zip(speeds, on, commands)]


@pytest.mark.parametrize("power_fmu", POWER_FMUS, ids=fmu_id)
def test_power_fmu_gives_the_model_dynamics_over_a_speed_ramp(power_fmu: Path) -> None:
    """The spindle dynamics of SpindlePower (J_spindle, k_speed_loop; the speed-rate state) over a run-up, a
    speed error at the command and a stop: the FMU's outputs equal models/power.py stepped the same way, and
    the inertia and speed-loop powers are what the ramp gives: J*n*slope, k*(n_cmd - n)*|n|; the rate is 0
    until the second step and the dynamic power 0 while the spindle is off."""
    require_fmu(power_fmu)
    model = model_of(power_fmu)
    h = 0.01
    parameters = {"P_standby": 0.0, "P_idle": 170.0, "c1": 0.02, "J_spindle": 1.5e-3, "k_speed_loop": 0.076}
    points = [{**parameters, **point} for point in spindle_run_up(h)]
    names = output_names(model)
    with Slave(power_fmu) as slave:
        slave.instantiate()
        slave.initialize(points[0])
        initial = slave.get(names)
        rows = []
        for point in points:
            slave.set(point)
            assert slave.step(h) == OK
            rows.append(slave.get(names))
    actual = np.array(rows)
    assert_close(initial, expected_outputs(model, points[0])[0])
    assert_close(actual, reference_trajectory(model, points, h))
    out = {name: actual[:, k] for k, name in enumerate(names)}
    n = np.array([p["spindle_speed"] for p in points])
    on = np.array([p["spindle_on"] for p in points])
    command = np.array([p["spindle_speed_command"] for p in points])
    rate = np.concatenate([[0.0], np.diff(n) / h])  # the first step has no previous speed
    assert rate[3:56] == pytest.approx(200 * np.pi)  # the ramp: 100 rev/s2
    np.testing.assert_allclose(out["spindle_acceleration"], rate, rtol=1e-12, atol=1e-9)
    dynamic = on * (1.5e-3 * n * rate + 0.076 * (command - n) * np.abs(n))
    np.testing.assert_allclose(out["P_dynamic"], dynamic, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(out["P_total"], on * (170.0 + 0.02 * np.abs(n)) + dynamic, rtol=1e-12)
    assert np.all(out["P_dynamic"][on == 0] == 0.0) and np.any(out["spindle_acceleration"][on == 0] < 0)


@pytest.mark.parametrize("power_fmu", POWER_FMUS, ids=fmu_id)
def test_power_fmu_without_dynamics_is_the_static_model(power_fmu: Path) -> None:
    """J_spindle and k_speed_loop at their defaults (0): over the same ramp, P_total is the static model's
    P_standby + on*(P_idle + c1*|n|), exactly, and P_dynamic is 0 (the speed rate is still an output)."""
    require_fmu(power_fmu)
    h = 0.01
    points = spindle_run_up(h)
    with Slave(power_fmu) as slave:
        slave.instantiate()
        slave.initialize(points[0])
        rows = []
        for point in points:
            slave.set(point)
            assert slave.step(h) == OK
            rows.append(slave.get(["P_total", "P_dynamic", "spindle_acceleration"]))
    actual = np.array(rows)
    n = np.array([p["spindle_speed"] for p in points])
    on = np.array([p["spindle_on"] for p in points])
    assert np.all(actual[:, 1] == 0.0)
    assert np.array_equal(actual[:, 0], 500.0 + on * (200.0 + 0.3 * np.abs(n)))  # the defaults
    assert np.max(actual[:, 2]) == pytest.approx(200 * np.pi)


def test_outputs_equal_the_model_over_a_random_grid(fmu: Path) -> None:
    """Random parameters within [min, max] and random inputs, 400 points (the corners included), each
    set, stepped and read through one instance: the outputs equal models.MODELS[id].evaluate(...)."""
    model = model_of(fmu)
    values = random_arguments(model, 400, np.random.default_rng(2024))
    actual = simulate_points(fmu, values, output_names(model))
    expected = reference_trajectory(model, points_of(values), 1e-3)
    assert actual.shape == expected.shape
    assert np.all(np.isfinite(actual))
    assert_close(actual, expected)
    assert np.count_nonzero(expected) > expected.size // 4  # not a grid of zeros


def test_outputs_are_up_to_date_with_inputs_in_initialization_mode(fmu: Path) -> None:
    model = model_of(fmu)
    values = random_arguments(model, 6, np.random.default_rng(3))
    with Slave(fmu) as slave:
        slave.instantiate()
        slave.enter_initialization()
        for i in range(2, 6):  # every change of a parameter or input shows in the next get
            slave.set(row(values, i))
            assert_close(slave.get(output_names(model)), expected_outputs(model, row(values, i))[0])
        slave.exit_initialization()
        assert slave.step(1e-3) in (OK, WARNING)
        assert_close(slave.get(output_names(model)), reference_trajectory(model, [row(values, 5)], 1e-3)[0])


def test_shared_library_exports_only_fmi_functions(fmu: Path) -> None:
    identifier, version = split_fmu_name(fmu)
    slave = Slave(fmu)
    slave.unload()
    platform = fmpy.platform if version == 2 else fmpy.platform_tuple
    library = Path(slave.unzipdir) / "binaries" / platform / f"{identifier}.so"
    assert library.is_file()
    listing = subprocess.run(["nm", "-D", "--defined-only", str(library)], check=True, capture_output=True,
                             text=True).stdout
    symbols = [line.split()[-1] for line in listing.splitlines() if line.strip()]
    assert f"fmi{version}DoStep" in symbols and f"fmi{version}GetVersion" in symbols
    foreign = [s for s in symbols if not s.startswith(f"fmi{version}")]
    assert not foreign, f"{library.name} exports non-FMI symbols: {foreign}"


# ---- an independent master: libcosim (FMI Library + libcosim, not fmpy) ----


def _fmpy_steps(fmu: Path, parameters: dict, inputs: list[dict], step_size: float) -> np.ndarray:
    model = model_of(fmu)
    with Slave(fmu) as slave:
        slave.instantiate()
        slave.initialize({**parameters, **inputs[0]})
        rows = []
        for point in inputs:
            slave.set(point)
            assert slave.step(step_size) <= 1
            rows.append(slave.get(output_names(model)))
    return np.array(rows)


def test_fmi2_fmu_runs_in_libcosim_like_in_fmpy(fmu2: Path) -> None:
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimManipulator import CosimManipulator
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave

    # FMI Library reports the start-less independent variable "time" as an error although FMI 2.0
    # (2.2.7, causality "independent") forbids a start value there; parsing succeeds regardless.
    log_output_level(CosimLogLevel.FATAL)
    model = model_of(fmu2)
    values = random_arguments(model, 12, np.random.default_rng(11))
    parameters = {v.name: float(values[v.name][5]) for v in numeric_parameters(model)}
    inputs = [{v.name: float(values[v.name][i]) for v in scalar_inputs(model)} for i in range(2, 12)]
    step_size = 1e-3

    execution = CosimExecution.from_step_size(int(step_size * 1e9))
    local = CosimLocalSlave(fmu_path=str(fmu2), instance_name="dut")
    index = execution.add_local_slave(local)
    assert index == 0
    variables = {v.name.decode(): v.reference for v in execution.slave_variables(index)}
    slave_md = fmpy.read_model_description(str(fmu2))
    assert variables == {v.name: v.valueReference for v in slave_md.modelVariables}
    observer = CosimObserver.create_last_value()
    assert execution.add_observer(observer)
    manipulator = CosimManipulator.create_override()
    assert execution.add_manipulator(manipulator)
    for name, value in {**parameters, **inputs[0]}.items():
        if model.variable(name).type == "Boolean":
            assert execution.boolean_initial_value(index, variables[name], bool(value))
        elif model.variable(name).type == "Int32":
            assert execution.integer_initial_value(index, variables[name], int(value))
        else:
            assert execution.real_initial_value(index, variables[name], value)

    outputs = [variables[n] for v in model.of("output") for n in (v.element_names() if v.shape else [v.name])]
    cosim = []
    for k, point in enumerate(inputs):
        for name, value in point.items():
            if model.variable(name).type == "Boolean":
                assert manipulator.slave_boolean_values(index, [variables[name]], [bool(value)])
            else:
                assert manipulator.slave_real_values(index, [variables[name]], [value])
        assert execution.step(1), execution.status()
        assert observer.last_real_values(index, [variables["time"]])[0] == pytest.approx((k + 1) * step_size)
        if all(model.variable(v.name).type == "Float64" for v in model.of("output")):
            cosim.append(observer.last_real_values(index, outputs))
        else:  # Int32 and Boolean outputs through their own getters
            readers = {"Float64": observer.last_real_values, "Int32": observer.last_integer_values,
                       "Boolean": observer.last_boolean_values}
            cosim.append([float(readers[v.type](index, [variables[v.name]])[0]) for v in model.of("output")])
    cosim = np.array(cosim)

    reference = _fmpy_steps(fmu2, parameters, inputs, step_size)
    assert_close(cosim, reference, what="libcosim vs fmpy")
    assert_close(cosim, reference_trajectory(model, [{**parameters, **p} for p in inputs], step_size))


# ---- rebuilding the binary from the FMU's sources/ ----


def test_binary_rebuilt_from_the_fmu_sources_gives_identical_outputs(fmu: Path, tmp_path: Path) -> None:
    """What `fmpy compile` does, on a copy: extract, build sources/ with fmpy's CMake project (the built
    binary removed first, so the rebuilt one is really used), zip again; then the same random grid."""
    identifier, version = split_fmu_name(fmu)
    unzipdir = tmp_path / "unzipped"
    fmpy.extract(str(fmu), unzipdir=str(unzipdir))
    platform = fmpy.platform if version == 2 else fmpy.platform_tuple
    library = unzipdir / "binaries" / platform / f"{identifier}.so"
    assert library.is_file()
    library.unlink()
    build = tmp_path / "cmake-build"
    build.mkdir()
    build_platform_binary(unzipdir, build_dir=build, cmake_options={"CMAKE_COMPILE_WARNING_AS_ERROR:BOOL": "ON"})
    assert library.is_file(), "fmpy's build did not produce the binary"
    shutil.rmtree(build)
    rebuilt = tmp_path / fmu.name
    create_zip_archive(rebuilt, unzipdir)

    assert validate_fmu(str(rebuilt)) == []
    model = model_of(fmu)
    values = random_arguments(model, 100, np.random.default_rng(5))
    original = simulate_points(fmu, values, output_names(model))
    again = simulate_points(rebuilt, values, output_names(model))
    assert np.array_equal(original, again), np.max(np.abs(original - again))
    assert_close(again, reference_trajectory(model, points_of(values), 1e-3))
