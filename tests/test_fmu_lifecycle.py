"""Many instantiate / initialize / step / free cycles of each FMU in one process: the resident memory
must not grow with the number of cycles (leaks; valgrind in ctest covers the C-level detail)."""
from __future__ import annotations

import ctypes
import gc
import os
from pathlib import Path

import numpy as np
import pytest

from fmu_helpers import (OK, WARNING, Slave, all_fmus, fmu_id, model_of, numeric_parameters, output_names,
                         reference_trajectory, require_fmu, scalar_inputs)

CYCLES = 2000
WARM_UP = 200
MAX_GROWTH = 1 << 20  # bytes per 900 cycles; a leaked instance per cycle adds ~1 MB, 4 snapshots ~1.2 MB
SNAPSHOTS = 4  # FMU states per cycle: a leaked snapshot (a few hundred bytes) must add up past MAX_GROWTH
PAGE_SIZE = os.sysconf("SC_PAGE_SIZE")


_LIBC = ctypes.CDLL(None)


def resident_bytes() -> int:
    """RSS after giving free heap memory back to the system (glibc malloc_trim): what remains is in use."""
    gc.collect()
    _LIBC.malloc_trim(0)
    with open("/proc/self/statm") as statm:
        return int(statm.read().split()[1]) * PAGE_SIZE


def one_cycle(slave: Slave, point: dict, outputs: list[str], expected: np.ndarray) -> None:
    """instantiate .. free on the already loaded library, touching every kind of call that allocates."""
    slave.messages.clear()
    slave.instantiate()
    slave.initialize(point)
    for _ in range(5):
        assert slave.step(1e-3) in (OK, WARNING)
    for _ in range(SNAPSHOTS):
        state = slave.fmu.getFMUState()
        data = slave.fmu.serializeFMUState(state)
        restored = slave.fmu.deserializeFMUState(data)
        slave.set_state(restored)
        slave.fmu.freeFMUState(restored)
        slave.fmu.freeFMUState(state)
    assert slave.step(1e-3) in (OK, WARNING)
    values = slave.get(outputs)
    slave.fmu.terminate()
    slave.free_instance()
    slave.time = 0.0
    assert np.array_equal(values, expected)


@pytest.mark.parametrize("fmu", all_fmus(), ids=fmu_id)
def test_repeated_lifecycles_do_not_grow_memory(fmu: Path) -> None:
    require_fmu(fmu)
    model = model_of(fmu)
    outputs = output_names(model)
    point = {v.name: 1.0 if v.type == "Boolean" else (v.min + v.max) // 3 if v.type == "Int32" else (v.min + v.max) / 3
             for v in numeric_parameters(model) + scalar_inputs(model)}
    expected = reference_trajectory(model, [point] * 6, 1e-3)[-1]  # the steps of one_cycle
    slave = Slave(fmu, "cycled")  # one extracted folder, the library loaded once
    try:
        for _ in range(WARM_UP):
            one_cycle(slave, point, outputs, expected)
        gc.collect()
        marks = [resident_bytes()]
        half = (CYCLES - WARM_UP) // 2
        for _ in range(2):
            for _ in range(half):
                one_cycle(slave, point, outputs, expected)
            gc.collect()
            marks.append(resident_bytes())
    finally:
        slave.unload()
    # A leak grows memory in both halves; the allocator settling (arenas, a heap that reached a new
    # size, other processes' pressure on a shared machine) shows once. Valgrind in ctest is the exact check.
    growth = [b - a for a, b in zip(marks, marks[1:])]
    assert min(growth) < MAX_GROWTH, (f"{fmu.name}: RSS grew by {growth[0] / 1024:.0f} KiB and "
                                      f"{growth[1] / 1024:.0f} KiB over two runs of {half} cycles")


FMI2_FMUS = [f for f in all_fmus() if f.stem.endswith("_fmi2")]


@pytest.mark.parametrize("fmu", FMI2_FMUS, ids=fmu_id)
def test_a_status_the_fmu_does_not_provide_is_discard_and_the_next_step_runs(fmu: Path) -> None:
    """FMI 2.0, 4.2.3: fmi2GetStatus and the typed status functions return fmi2Discard for a status the FMU does
    not provide, without putting the instance in the Error state; fmi2LastSuccessfulTime and fmi2Terminated are
    provided."""
    import fmpy.fmi2 as fmi2

    require_fmu(fmu)
    slave = Slave(fmu)
    slave.instantiate()
    slave.initialize({})
    assert slave.step(1e-3) in (OK, WARNING)
    status = fmi2.fmi2Status()
    integer, string, real, boolean = fmi2.fmi2Integer(), fmi2.fmi2String(), fmi2.fmi2Real(), fmi2.fmi2Boolean()
    component = slave.fmu.component
    discard = 2
    assert slave.fmu.dll.fmi2GetStatus(component, fmi2.fmi2DoStepStatus, ctypes.byref(status)) == discard
    assert slave.fmu.dll.fmi2GetIntegerStatus(component, fmi2.fmi2DoStepStatus, ctypes.byref(integer)) == discard
    assert slave.fmu.dll.fmi2GetStringStatus(component, fmi2.fmi2PendingStatus, ctypes.byref(string)) == discard
    assert slave.fmu.dll.fmi2GetRealStatus(component, fmi2.fmi2DoStepStatus, ctypes.byref(real)) == discard
    assert slave.fmu.dll.fmi2GetRealStatus(component, fmi2.fmi2LastSuccessfulTime, ctypes.byref(real)) == 0
    assert real.value == pytest.approx(1e-3)
    assert slave.fmu.dll.fmi2GetBooleanStatus(component, fmi2.fmi2Terminated, ctypes.byref(boolean)) == 0
    assert slave.step(1e-3) in (OK, WARNING)                    # not in the Error state
    assert slave.fmu.dll.fmi2GetStatus(component, fmi2.fmi2DoStepStatus, None) == 3   # a NULL value is an Error
    assert any("value is NULL" in m for m in map(str, slave.messages))
    slave.free_instance()                                       # (Error: only reset or free is allowed now)
