"""Shared helpers of the FMU tests (tests/test_fmu_*.py): where the built FMUs are, which ones are
expected, and a thin driver over fmpy's low-level FMU2Slave/FMU3Slave that captures the FMU's log
messages and returns the FMI status of each call instead of hiding warnings.

Imported as ``from fmu_helpers import ...`` (pytest's default ``prepend`` import mode puts tests/
on sys.path); the sanitizer test also runs this module as a script in a subprocess (see the end).
"""
from __future__ import annotations

import atexit
import ctypes
import os
import shutil
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable, Sequence

import numpy as np

REPO = Path(__file__).resolve().parents[1]

from fmpy import calloc, extract, free, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (
    FMU2Slave,
    fmi2CallbackAllocateMemoryTYPE,
    fmi2CallbackFreeMemoryTYPE,
    fmi2CallbackFunctions,
    fmi2CallbackLoggerTYPE,
    fmi2True,
)
from fmpy.fmi3 import FMU3Slave, fmi3Boolean, fmi3Float64

OK, WARNING, DISCARD, ERROR, FATAL = 0, 1, 2, 3, 4

ENV_FMU_DIR = "MILLING_TWIN_FMU_DIR"


def repo_root() -> Path:
    return REPO


def fmu_dir() -> Path:
    """Folder of the built FMUs: $MILLING_TWIN_FMU_DIR, else <repo>/build/fmus."""
    return Path(os.environ.get(ENV_FMU_DIR, REPO / "build" / "fmus"))


def generated_dir(identifier: str = "ForceNet") -> Path:
    """What the build generated for ``identifier`` (model_constants.h, ...), beside the built FMUs: the C
    sources a test compiles on its own include it from there."""
    folder = fmu_dir().parent / "generated" / identifier
    if not (folder / "model_constants.h").is_file():
        raise FileNotFoundError(f"{folder / 'model_constants.h'} is missing: build the FMUs first (make fmus)")
    return folder


def fmu_file_name(identifier: str, fmi_version: int) -> str:
    return f"{identifier}.fmu" if fmi_version == 3 else f"{identifier}_fmi{fmi_version}.fmu"


def split_fmu_name(path: Path | str) -> tuple[str, int]:
    """``SpindlePower.fmu`` -> ("SpindlePower", 3); ``SpindlePower_fmi2.fmu`` -> ("SpindlePower", 2)."""
    stem = Path(path).name.removesuffix(".fmu")
    if stem.endswith("_fmi2"):
        return stem.removesuffix("_fmi2"), 2
    return stem, 3


def expected_fmus(folder: Path | None = None) -> list[Path]:
    """The FMUs the build must produce: every model in models.MODELS, FMI 3.0 and FMI 2.0."""
    from milling_twin.models import MODELS

    folder = fmu_dir() if folder is None else folder
    return [folder / fmu_file_name(identifier, version) for identifier in MODELS for version in (3, 2)]


def all_fmus(folder: Path | None = None) -> list[Path]:
    """Expected FMUs plus whatever else lies in the folder, sorted. Missing ones are kept in the list so
    the tests parametrized over it fail (``require_fmu``) instead of being skipped for lack of parameters."""
    folder = fmu_dir() if folder is None else folder
    found = set(folder.glob("*.fmu")) if folder.is_dir() else set()
    return sorted(found | set(expected_fmus(folder)))


def fmu_id(path: Path) -> str:
    return path.name.removesuffix(".fmu")


def require_fmu(path: Path) -> Path:
    """Fail (never skip) when the FMU was not built: the test command always builds first."""
    import pytest

    folder = path.parent
    if not folder.is_dir() or not any(folder.glob("*.fmu")):
        pytest.fail(f"no FMUs in {folder}: build first (cmake --build build) or set {ENV_FMU_DIR}")
    if not path.is_file():
        pytest.fail(f"{path} was not built")
    return path


# ---- extracted FMUs, shared by all tests of a process ----

_EXTRACTED: dict[Path, str] = {}


def _remove_extracted() -> None:
    for folder in _EXTRACTED.values():
        shutil.rmtree(folder, ignore_errors=True)
    _EXTRACTED.clear()


atexit.register(_remove_extracted)


def extracted(path: Path) -> str:
    """The FMU unzipped once per process (removed at exit)."""
    path = Path(path).resolve()
    if path not in _EXTRACTED:
        _EXTRACTED[path] = extract(str(path), unzipdir=tempfile.mkdtemp(prefix=f"{path.stem}_"))
    return _EXTRACTED[path]


# ---- log capture ----


@dataclass(frozen=True)
class LogMessage:
    status: int
    category: str
    message: str
    raw: str = ""  # FMI 2: the message as the FMU passed it, a printf format with '%' and '#' escaped


def _text(value: bytes | None) -> str:
    return "" if value is None else value.decode("utf-8", errors="replace")


def unescape_fmi2_message(raw: str) -> str:
    """An FMI 2 log message is a printf format in which '#' delimits value references: a literal '%' or '#'
    comes as '%%' or '##'. Returns the text; raises ValueError on an unescaped '%' or '#' (an importer
    would read missing printf arguments or take it for a value reference)."""
    marked = raw.replace("%%", "\0").replace("##", "\1")
    if "%" in marked or "#" in marked:
        raise ValueError(f"unescaped '%' or '#' in FMI 2 log message {raw!r}")
    return marked.replace("\0", "%").replace("\1", "#")


def fmi2_callbacks(sink: list[LogMessage]) -> fmi2CallbackFunctions:
    """fmi2CallbackFunctions whose logger appends to ``sink``. fmpy's native printf proxy (addLoggerProxy)
    is not used: it keeps the Python logger in one global, so with two instances every message would go to
    the logger installed last. The message carries no printf arguments from our FMUs, so unescaping
    ``%%`` and ``##`` gives what printf would print."""

    def logger(environment, instance_name, status, category, message):  # noqa: ARG001
        raw = _text(message)
        sink.append(LogMessage(int(status), _text(category), unescape_fmi2_message(raw), raw))

    callbacks = fmi2CallbackFunctions()
    callbacks.logger = fmi2CallbackLoggerTYPE(logger)
    callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
    callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
    return callbacks


def fmi3_logger(sink: list[LogMessage]) -> Callable:
    """A Python function for FMU3Slave.instantiate(logMessage=...) that appends to ``sink``."""

    def log_message(environment, status, category, message):  # noqa: ARG001
        sink.append(LogMessage(int(status), _text(category), _text(message)))

    return log_message


def status_of(call: Callable[[], object]) -> int:
    """Status of an fmpy call: fmpy raises FMICallException for Discard/Error/Fatal, returns otherwise."""
    try:
        call()
    except FMICallException as exception:
        return exception.status
    return OK


# ---- a driver for one FMU instance ----


class Slave:
    """One instance of a co-simulation FMU through fmpy's FMU2Slave/FMU3Slave, with its log captured.

    Variables are addressed by name. ``step`` returns the FMI status (Warning included, which fmpy's
    doStep swallows); the other calls raise fmpy's FMICallException on Error like fmpy does.
    """

    def __init__(self, path: Path | str, instance_name: str = "instance", guid: str | None = None,
                 unzipdir: str | None = None):
        self.path = Path(path)
        self.identifier, self.fmi_version = split_fmu_name(self.path)
        self.unzipdir = unzipdir or extracted(self.path)
        self.md = read_model_description(self.unzipdir)
        assert self.md.coSimulation.modelIdentifier == self.identifier
        self.variables = {v.name: v for v in self.md.modelVariables}
        self.vr = {v.name: v.valueReference for v in self.md.modelVariables}
        # arrays: FMI 3 has one variable with dimensions; FMI 2 one scalar per element, "name[i,j]"
        self.sizes = {v.name: int(np.prod([int(d.start) for d in v.dimensions])) for v in self.md.modelVariables
                      if getattr(v, "dimensions", None)}
        self.elements: dict[str, list[int]] = {}
        for v in self.md.modelVariables:
            if "[" in v.name:
                self.elements.setdefault(v.name.split("[")[0], []).append(v.valueReference)
        self.messages: list[LogMessage] = []
        cls = FMU3Slave if self.fmi_version == 3 else FMU2Slave
        self.fmu = cls(guid=self.md.guid if guid is None else guid, modelIdentifier=self.identifier,
                       unzipDirectory=self.unzipdir, instanceName=instance_name)
        self.prefix = f"fmi{self.fmi_version}"
        self._callbacks = None
        self.time = 0.0
        self.library_loaded = True

    # -- lifetime --
    def instantiate(self, logging_on: bool = False) -> None:
        self.time = 0.0
        if self.fmi_version == 3:
            self.fmu.instantiate(loggingOn=logging_on, logMessage=fmi3_logger(self.messages))
        else:
            self._callbacks = fmi2_callbacks(self.messages)
            self.fmu.instantiate(callbacks=self._callbacks, loggingOn=logging_on)

    def free_instance(self) -> None:
        """Frees the instance only; the library stays loaded (see ``unload``)."""
        if self.fmu.component:
            getattr(self.fmu, f"{self.prefix}FreeInstance")(self.fmu.component)
            self.fmu.component = None

    def unload(self) -> None:
        self.free_instance()
        if self.library_loaded:
            self.fmu.freeLibrary()
            self.library_loaded = False

    def __enter__(self) -> "Slave":
        return self

    def __exit__(self, *exc) -> None:
        self.unload()

    # -- modes --
    def enter_initialization(self, start_time: float = 0.0, stop_time: float | None = None) -> None:
        if self.fmi_version == 3:
            self.fmu.enterInitializationMode(startTime=start_time, stopTime=stop_time)
        else:
            self.fmu.setupExperiment(startTime=start_time, stopTime=stop_time)
            self.fmu.enterInitializationMode()
        self.time = start_time

    def exit_initialization(self) -> None:
        self.fmu.exitInitializationMode()

    def initialize(self, values: dict[str, float] | None = None, start_time: float = 0.0) -> None:
        self.enter_initialization(start_time)
        if values:
            self.set(values)
        self.exit_initialization()

    def step(self, step_size: float, current_time: float | None = None) -> int:
        """One doStep from ``current_time`` (default: the time reached so far); returns the status."""
        t = self.time if current_time is None else current_time
        try:
            if self.fmi_version == 3:
                flags = [fmi3Boolean() for _ in range(3)]
                last = fmi3Float64()
                status = self.fmu.fmi3DoStep(self.fmu.component, t, step_size, fmi3Boolean(True),
                                             *(ctypes.byref(f) for f in flags), ctypes.byref(last))
            else:
                status = self.fmu.fmi2DoStep(self.fmu.component, t, step_size, fmi2True)
        except FMICallException as exception:
            return exception.status
        if status <= WARNING:
            self.time = t + step_size
        return status

    def set_state(self, state) -> None:
        """setFMUstate, then continue from the restored time (read back from the FMU)."""
        self.fmu.setFMUState(state)
        self.time = float(self.get(["time"])[0])

    # -- values --
    def is_boolean(self, name: str) -> bool:
        return self.variables[name].type == "Boolean"

    def is_fixed(self, name: str) -> bool:
        return self.variables[name].variability == "fixed"

    def set(self, values: dict[str, float | bool], include_fixed: bool = True) -> None:
        """Set by name (Float64, Int32, Boolean); ``include_fixed=False`` leaves out fixed
        parameters, which may only be set before initialization ends."""
        values = {n: v for n, v in values.items() if include_fixed or not self.is_fixed(n)}
        kinds = {n: self.variables[n].type for n in values}
        reals = {n: float(v) for n, v in values.items() if kinds[n] in ("Real", "Float64")}
        integers = {n: int(v) for n, v in values.items() if kinds[n] in ("Integer", "Int32")}
        booleans = {n: bool(v) for n, v in values.items() if kinds[n] == "Boolean"}
        if reals:
            self.set_real([self.vr[n] for n in reals], list(reals.values()))
        if integers:
            setter = self.fmu.setInt32 if self.fmi_version == 3 else self.fmu.setInteger
            setter([self.vr[n] for n in integers], list(integers.values()))
        if booleans:
            vrs = [self.vr[n] for n in booleans]
            self.fmu.setBoolean(vrs, list(booleans.values()))

    def set_real(self, vrs: Sequence[int], values: Sequence[float]) -> None:
        if self.fmi_version == 3:
            self.fmu.setFloat64(list(vrs), list(values))
        else:
            self.fmu.setReal(list(vrs), list(values))

    def get_real(self, vrs: Sequence[int], n_values: int | None = None) -> list[float]:
        if self.fmi_version == 3:
            return self.fmu.getFloat64(list(vrs), nValues=n_values)
        return self.fmu.getReal(list(vrs))

    def get(self, names: Iterable[str]) -> np.ndarray:
        """Float64 values by name; an array contributes all its elements (row-major) in either version.
        Int32 and Boolean scalars are read with their own getters and returned as numbers."""
        names = list(names)
        if any(self.variables[n].type in ("Integer", "Int32", "Boolean") for n in names if n in self.variables):
            return np.array([self._scalar(n) for n in names], dtype=float)
        vrs: list[int] = []
        count = 0
        for n in names:
            if n in self.elements:  # FMI 2: the array's scalars
                vrs += self.elements[n]
                count += len(self.elements[n])
            else:
                vrs.append(self.vr[n])
                count += self.sizes.get(n, 1)
        return np.array(self.get_real(vrs, n_values=count if self.fmi_version == 3 else None), dtype=float)

    def _scalar(self, name: str) -> float:
        kind, vr = self.variables[name].type, [self.vr[name]]
        if kind in ("Integer", "Int32"):
            return float((self.fmu.getInt32 if self.fmi_version == 3 else self.fmu.getInteger)(vr)[0])
        if kind == "Boolean":
            return float(self.fmu.getBoolean(vr)[0])
        return float(self.get_real(vr)[0])

    # -- log --
    def errors(self) -> list[str]:
        return [m.message for m in self.messages if m.status == ERROR]

    def warnings(self) -> list[str]:
        return [m.message for m in self.messages if m.status == WARNING]

    def last_error(self) -> str:
        errors = self.errors()
        assert errors, f"no error was logged; log: {self.messages}"
        return errors[-1]


# ---- model data ----


def model_of(path: Path | str):
    from milling_twin.models import MODELS

    identifier, _ = split_fmu_name(path)
    return MODELS[identifier]


def random_arguments(model, count: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """``count`` random points of every parameter and input, uniform within [min, max] (booleans 0/1).
    The first rows are the corners min and max, and every Boolean combination is represented.
    A model whose reference module (NATIVE_REFERENCES) has its own ``random_arguments`` gets those:
    valid operating points of that model, with fixed parameters constant."""
    native = native_reference(model)
    if native is not None and hasattr(native, "random_arguments"):
        return native.random_arguments(count, rng)
    values: dict[str, np.ndarray] = {}
    for v in numeric_parameters(model) + scalar_inputs(model):
        if v.type == "Boolean":
            column = rng.integers(0, 2, count).astype(float)
            column[:2] = [0.0, 1.0]
        elif v.type == "Int32":
            column = rng.integers(int(v.min), int(v.max) + 1, count).astype(float)
            column[:2] = [v.min, v.max]
        else:
            column = rng.uniform(v.min, v.max, count)
            column[:2] = [v.min, v.max]
        if v.effective_variability == "fixed":  # set once, before initialization ends
            column[:] = column[min(1, count - 1)]
        values[v.name] = column
    return values


def is_stateless(model) -> bool:
    """Outputs depend only on the current parameters and inputs, all generated from models/: then
    after any step the outputs equal ``model.evaluate`` at that point."""
    return not model.states and not model.native_outputs


def points_of(values: dict[str, np.ndarray]) -> list[dict[str, float]]:
    count = len(next(iter(values.values())))
    return [row(values, i) for i in range(count)]


# Models with outputs or states computed by their own C code (``native_outputs``/``native_states``)
# -> the module of models/ with the Python reference implementation of that code, providing
# ``reference_trajectory(points, step_size)`` (the protocol of the function below) and
# ``initial_outputs(values)`` (outputs before any step, points x outputs, like expected_outputs).
# A module may also provide ``random_arguments(count, rng)`` when not every point of the box of ranges is
# valid for its model (a tool larger than the stock, a path that jumps): random_arguments uses it.
NATIVE_REFERENCES = {"CuttingForce": "milling_twin.models.cutting_force", "Workpiece": "milling_twin.models.workpiece",
                     "Interpolator": "milling_twin.models.interpolator", "ForceNet": "milling_twin.models.force_net"}


def native_reference(model):
    """The reference module of a model with native parts (see NATIVE_REFERENCES), else None."""
    if not (model.native_states or model.native_outputs):
        return None
    if model.identifier not in NATIVE_REFERENCES:
        raise AssertionError(f"{model.identifier} computes {model.native_states + model.native_outputs} in C: "
                             "register the module of its reference implementation in NATIVE_REFERENCES")
    import importlib

    return importlib.import_module(NATIVE_REFERENCES[model.identifier])


def keeps_heap_data(model) -> bool:
    """Models with native parts keep their data (buffers, grids) in the instance heap, so their FMU
    state is longer than the wrapper's fixed-size header; the others' state is the header alone."""
    return bool(model.native_states or model.native_outputs)


def reference_trajectory(model, points: Sequence[dict[str, float]], step_size: float) -> np.ndarray:
    """What an FMU generated from ``model`` must give for: initialize with points[0], then for
    each point set it and do one step of ``step_size``, reading the outputs after the step.
    States follow ``model.step`` from their start values (points x outputs); models with native
    parts follow their reference implementation (NATIVE_REFERENCES)."""
    native = native_reference(model)
    if native is not None:
        return np.asarray(native.reference_trajectory(points, step_size), dtype=float)
    states = {s.name: s.start for s in model.states}
    rows = []
    for point in points:
        if model.states:
            new = model.step(step_size, **point, **states)
            states = {name: float(value) for name, value in new.items()}
        rows.append(expected_outputs(model, {**point, **states})[0])
    return np.array(rows)


def row(values: dict[str, np.ndarray], i: int) -> dict[str, float]:
    return {name: float(column[i]) for name, column in values.items()}


def output_names(model) -> list[str]:
    return [v.name for v in model.of("output")]


def scalar_inputs(model) -> tuple:
    """The inputs the generic tests set from random points: all but arrays (an array input, such as ForceNet's
    engagement map, keeps its start value here; tests/test_fmu_bad_input.py and the model's own tests cover
    it)."""
    return tuple(v for v in model.of("input") if not v.shape)


def numeric_parameters(model) -> tuple:
    """The parameters tests set from numbers: all but String ones (a file name such as a part program keeps
    its start value)."""
    return tuple(v for v in model.of("parameter") if v.type != "String" and not v.shape)


def expected_outputs(model, values: dict[str, np.ndarray | float]) -> np.ndarray:
    """Model outputs from the casadi definition as an array (points x outputs); for models with
    native parts, the outputs before any step from their reference implementation."""
    native = native_reference(model)
    if native is not None:
        return np.asarray(native.initial_outputs(values), dtype=float)
    result = model.evaluate(**values)
    return np.stack([np.atleast_1d(result[name]) for name in output_names(model)], axis=-1)


def assert_close(actual, expected, rtol: float = 1e-12, what: str = "") -> None:
    """Relative agreement, where "relative" is to the value or, for values decaying through many
    orders of magnitude (a damped response), to the largest magnitude of its column."""
    actual, expected = np.asarray(actual, dtype=float), np.asarray(expected, dtype=float)
    assert actual.shape == expected.shape, f"{what}: shapes {actual.shape} != {expected.shape}"
    scale = np.max(np.abs(expected), axis=0, keepdims=True) if expected.ndim else np.abs(expected)
    error = np.abs(actual - expected)
    bad = ~(error <= rtol * np.maximum(np.abs(expected), scale))  # NaN counts as bad
    assert not np.any(bad), (f"{what}: {np.count_nonzero(bad)} of {bad.size} values differ by more than "
                             f"{rtol:g} relative; first at {np.argwhere(bad)[0].tolist()}: "
                             f"{actual[bad][0]!r} != {expected[bad][0]!r}")


# ---- a full exercise of one FMU, run in-process or under the sanitizers in a subprocess ----
# (no import of models/ here: the sanitizer subprocess loads only fmpy and the FMU)


def simulate_points(path: Path, values: dict[str, Sequence[float]], outputs: Sequence[str],
                    step_size: float = 1e-3) -> np.ndarray:
    """One instance: every point set in turn (parameters are tunable), one doStep each, outputs read
    after the step. The first point is also read in initialization mode. Returns (points x outputs)."""
    values = {name: np.asarray(column, dtype=float) for name, column in values.items()}
    count = len(next(iter(values.values())))
    rows = []
    with Slave(path) as slave:
        slave.instantiate()
        slave.enter_initialization()
        slave.set(row(values, 0))
        init_outputs = slave.get(outputs)
        slave.exit_initialization()
        assert np.array_equal(init_outputs, slave.get(outputs)), "outputs changed when leaving initialization"
        for i in range(count):
            slave.set(row(values, i), include_fixed=False)
            status = slave.step(step_size)
            assert status in (OK, WARNING), f"doStep at point {i} returned {status}: {slave.messages[-3:]}"
            rows.append(slave.get(outputs))
        assert slave.get(["time"])[0] == slave.time
        slave.fmu.terminate()
    return np.array(rows)


def bad_calls(path: Path) -> list[str]:
    """A tour of rejected calls on one instance (each followed by reset); returns the error messages."""
    with Slave(path) as slave:
        variables = slave.md.modelVariables
        parameter = next(v for v in variables if v.causality == "parameter" and v.max is not None)
        real_input = next(v for v in variables if v.causality == "input" and v.type != "Boolean")
        output = next(v for v in variables if v.causality == "output")
        slave.instantiate()
        statuses = {"doStep before initialization": slave.step(1e-3)}
        slave.fmu.reset()
        too_big = float(parameter.max) * 2 + 1
        statuses["out of range"] = status_of(lambda: slave.set({parameter.name: too_big}))
        slave.fmu.reset()
        statuses["nan"] = status_of(lambda: slave.set({real_input.name: float("nan")}))
        slave.fmu.reset()
        statuses["unknown vr"] = status_of(lambda: slave.set_real([10_000], [0.0]))
        slave.fmu.reset()
        statuses["set output"] = status_of(lambda: slave.set({output.name: 1.0}))
        slave.fmu.reset()
        slave.initialize()
        statuses["wrong time"] = slave.step(1e-3, current_time=0.5)
        slave.fmu.reset()
        slave.initialize()
        statuses["zero step"] = slave.step(0.0)
        statuses["in error state"] = slave.step(1e-3)
        slave.fmu.reset()
        slave.initialize()
        state = slave.fmu.getFMUState()
        data = slave.fmu.serializeFMUState(state)
        statuses["short state"] = status_of(lambda: slave.fmu.deserializeFMUState(data[:-1]))
        slave.fmu.reset()
        slave.initialize()
        restored = slave.fmu.deserializeFMUState(data)
        slave.set_state(restored)
        slave.fmu.freeFMUState(restored)
        slave.fmu.freeFMUState(state)
        assert slave.step(1e-3) == OK
        bad = {name: s for name, s in statuses.items() if s != ERROR}
        assert not bad, f"{path.name}: expected Error from {bad}"
        return slave.errors()


if __name__ == "__main__":
    # python fmu_helpers.py JOB.json: the sanitizer test's subprocess. JOB.json holds
    # {"<fmu path>": {"values": {name: [...]}, "outputs": [names]}}; the results are written back to
    # JOB.json's "results" as {"<fmu path>": {"outputs": [[...]], "errors": [...]}}.
    import json

    job_file = Path(sys.argv[1])
    job = json.loads(job_file.read_text())
    results = {}
    for fmu_path, spec in job["fmus"].items():
        outputs = simulate_points(Path(fmu_path), spec["values"], spec["outputs"])
        results[fmu_path] = {"outputs": outputs.tolist(), "errors": bad_calls(Path(fmu_path))}
    job["results"] = results
    job_file.write_text(json.dumps(job))
    _remove_extracted()
    print(f"exercised {len(results)} FMUs")


# ---- both stepping paths of one scenario ----

def bits(frame) -> np.ndarray:
    """A results frame's values as their bit patterns (equal only when bit for bit equal)."""
    return frame.to_numpy(dtype=np.float64).view(np.uint64)


def run_both(scenario, out: Path, must_complete: bool = True, **kwargs) -> dict:
    """{path: (RunResult, frame)} of ``scenario`` on the Python and the fast path (``kwargs``: more of ``run``'s)."""
    from milling_twin.orchestrator.master import run
    from milling_twin.orchestrator.results import load_results

    both = {}
    for path in ("python", "fast"):
        result = run(scenario, out / path, progress=False, stepping=path, **kwargs)
        assert result.stepping == path and (result.status == "completed" or not must_complete), result.status
        both[path] = result, load_results(result.run_dir)
    return both
