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
