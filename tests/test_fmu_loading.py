"""milling_twin.orchestrator.fmu_loading: fmpy's slaves with the FMI function table introspected once per class bind
exactly the functions fmpy binds, with the same ctypes signatures, and run an FMU the same way."""
from __future__ import annotations

import subprocess
import sys

import fmpy.fmi2
import fmpy.fmi3
import pytest
from fmpy import read_model_description

from fmu_helpers import fmi2_callbacks, fmi3_logger
from milling_twin.orchestrator import fmu_cache, fmu_loading
from milling_twin.orchestrator.results import sha256_of

CASES = [("SpindlePower_fmi2.fmu", fmpy.fmi2.FMU2Slave, fmu_loading.FMU2Slave),
         ("SpindlePower.fmu", fmpy.fmi3.FMU3Slave, fmu_loading.FMU3Slave),
         ("Workpiece.fmu", fmpy.fmi3.FMU3Slave, fmu_loading.FMU3Slave)]


def _load(cls, fmu_dir, name):
    path = fmu_dir / name
    folder = fmu_cache.unpack(path, sha256_of(path)).folder
    md = read_model_description(folder)
    return cls(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
               instanceName="probe"), md


@pytest.mark.parametrize("name, fmpy_cls, our_cls", CASES)
def test_the_same_functions_with_the_same_signatures_as_fmpy(fmu_dir, name, fmpy_cls, our_cls):
    theirs, _ = _load(fmpy_cls, fmu_dir, name)
    ours, _ = _load(our_cls, fmu_dir, name)
    ours_again, _ = _load(our_cls, fmu_dir, name)  # the second instance uses the cached table
    assert len(theirs._functions) > 30
    for fmu in (ours, ours_again):
        assert sorted(fmu._functions) == sorted(theirs._functions)
        for fn, expected in theirs._functions.items():
            got = fmu._functions[fn]
            assert (got.argnames, got.argtypes, got.restype) == \
                   (expected.argnames, expected.argtypes, expected.restype), fn
            assert ctypes_address(got) == ctypes_address(expected), fn  # the same symbol of the library
    for fmu in (theirs, ours, ours_again):
        fmu.freeLibrary()


def ctypes_address(function) -> int:
    import ctypes

    return ctypes.cast(function, ctypes.c_void_p).value


@pytest.mark.parametrize("name, fmpy_cls, our_cls", CASES[:2])
def test_an_instance_steps_and_reports_errors_as_with_fmpy(fmu_dir, name, fmpy_cls, our_cls):
    results = []
    for cls in (fmpy_cls, our_cls):
        fmu, md = _load(cls, fmu_dir, name)
        vr = {v.name: v.valueReference for v in md.modelVariables}
        fmi3 = cls.__name__ == "FMU3Slave"
        messages: list = []
        # not fmpy's default FMI 2 callbacks: their native proxy calls whatever logger was installed last in the
        # process (fmpy.simulate_fmu leaves its own, freed, there: tests/test_fmu_compliance.py runs it)
        callbacks = None if fmi3 else fmi2_callbacks(messages)
        if fmi3:
            fmu.instantiate(logMessage=fmi3_logger(messages))
        else:
            fmu.instantiate(callbacks=callbacks)
        set_real, get_real = (fmu.setFloat64, fmu.getFloat64) if fmi3 else (fmu.setReal, fmu.getReal)
        set_real([vr["spindle_speed"]], [100.0])
        if fmi3:
            fmu.enterInitializationMode(startTime=0.0)
        else:
            fmu.setupExperiment(startTime=0.0)
            fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        fmu.doStep(0.0, 1e-3)
        results.append(get_real([vr["P_total"]]))
        with pytest.raises(fmpy.fmi1.FMICallException):  # NaN input: an FMI error, raised as fmpy raises it
            set_real([vr["spindle_speed"]], [float("nan")])
        assert any("spindle_speed" in m.message for m in messages), messages
        fmu.freeInstance()  # the Error state allows no Terminate; fmpy's freeInstance also unloads the library
    assert results[0] == results[1]


_TIMING = """
import sys, time
import fmpy.fmi3
from fmpy import read_model_description
from milling_twin.orchestrator import fmu_loading
folder = sys.argv[1]
md = read_model_description(folder)
best = {fmpy.fmi3.FMU3Slave: float("inf"), fmu_loading.FMU3Slave: float("inf")}
for _ in range(9):
    for cls in best:
        t0 = time.perf_counter()
        fmu = cls(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName="probe")
        best[cls] = min(best[cls], time.perf_counter() - t0)
        fmu.freeLibrary()
print(best[fmu_loading.FMU3Slave], best[fmpy.fmi3.FMU3Slave])
"""


def test_loading_is_cheaper_than_fmpys(fmu_dir):
    """The point of the module: constructing a slave (load the library, bind its functions) costs less than
    fmpy's. Only the construction is timed (unpacking and reading the model description are the same for
    both), best of 9 alternating, in a process of its own: pytest's process has hundreds of libraries
    loaded, which makes every dlopen slower and noisier than in a simulation's process."""
    path = fmu_dir / "SpindlePower.fmu"
    folder = fmu_cache.unpack(path, sha256_of(path)).folder
    proc = subprocess.run([sys.executable, "-c", _TIMING, str(folder)], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    ours, fmpys = map(float, proc.stdout.split())
    assert ours < 0.6 * fmpys, (ours, fmpys)
