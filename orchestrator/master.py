"""Fixed-grid Gauss-Seidel co-simulation master on fmpy.

Semantics of :func:`run` (``base`` = the scenario's base step, ``t_k = start + k*base``):

* Grid. The run covers ``n_out = floor((stop - start) / output_interval)`` output
  intervals, i.e. ticks ``k = 0 .. N-1`` with ``N = n_out * ticks_per_output``; it
  ends at ``t_N``, the last output time not after ``stop_time``. An instance with
  ``step_size = m*base`` is due at the ticks ``k`` with ``k % m == 0`` and steps
  ``doStep(t_k, t_{min(k+m, N)} - t_k)`` (so a slower instance's last step is cut
  at ``t_N``, and ``t + h`` lands exactly on the next grid time).
* Setup. Each instance is instantiated, its scenario parameters and constant inputs
  are set (still in the Instantiated state, i.e. as start values before initialization), then all
  enter Initialization Mode at ``start`` (FMI 2: ``setupExperiment`` first). In
  execution order each instance's inputs are set from the values at ``start`` and
  its outputs read, so later instances see them; then all exit Initialization
  Mode. Inputs that nothing feeds keep their start (or constant scenario) values.
* One tick at ``t_k``: first the outputs feeding ``delay = true`` connections are
  copied (their values at the beginning of the tick). Then, in execution order,
  every due instance gets its inputs set and steps:
  recorded channels are sampled at ``t_k`` (``linear`` or ``hold``; booleans hold, except
  threshold channels, which switch where their interpolated column crosses the threshold);
  a non-delayed connection passes the source's latest output: sources precede
  their targets, so a source due at ``t_k`` has already stepped to its next
  communication point (Gauss-Seidel); a delayed connection passes the copy taken
  at the beginning of the tick, i.e. the source's value at its previous
  communication point. Unit factors are applied on the way. Outputs are read
  right after the step only where connections need them.
* Variable communication step (``[stepping]``, :class:`~milling_twin.orchestrator.scenario.Stepping`; without
  it every interval is fine and nothing below applies). The ticks are cut into coarse intervals
  ``[cM, (c+1)M)`` of ``M = coarse_step / base`` ticks (the last one cut at ``N``). At the first tick ``cM`` of
  each interval, at the point of the execution order where the first variable instance would step (after the
  other instances before it, among them every gate instance, which steps at exactly ``coarse_step`` and so has
  already stepped to ``t_min((c+1)M, N)``: Gauss-Seidel), the master evaluates the ``fine_when`` conditions on
  the gate outputs as last read (Real: ``value > threshold`` or ``value < threshold`` in the output's unit;
  Boolean: ``value == is``). The interval is fine if a condition holds now or held at one of the ``H =
  hold_intervals`` evaluations before it (default 1: the previous one; before the first interval none held):
  the condition now speaks of the interval's end, the previous one of its start, so the interval in which the
  tool enters or leaves material is fine, and with ``H > 1`` the ``H - 1`` intervals after it too. Every
  interval counts as fine or coarse once, when evaluated. In a fine interval the variable instances step on
  their own step size, as without ``[stepping]``. In a coarse interval each variable instance is due once, at
  ``cM``, and makes one ``doStep(t_cM, t_min((c+1)M, N) - t_cM)``, its inputs set at that tick as above;
  recorded rows inside the interval hold its outputs from that step (the step covering that time, as for a
  slower instance). Delayed connections still pass the copy taken at the start of the tick, every tick.
* Parameter changes at events (``[[on_change]]``, :class:`~milling_twin.orchestrator.scenario.OnChange`). The
  watched output (Int32 or Boolean) is read after every step of its instance. At the start of each tick ``k``
  that is a communication point of that instance (``k % m == 0``, its own ``m``: a trigger's instance is never
  a variable one), before the delayed copies and before any instance steps, the master compares the output's
  value (as left by the instance's step ending at ``t_k``) with its value at the previous such point (at
  ``k = 0``: the value after initialization, so nothing fires there). If it changed and now equals ``equals``,
  the entry fires: its ``set`` values are set (one FMI set call each, in the order written); then the tick
  proceeds as usual, so each target uses its new value from its next doStep on (the one from ``t_k`` where
  due at ``k``). Several entries may fire at one tick, in file order; an entry whose output changed to
  another value does not fire, but the new value is remembered. A change at the run's last point ``t_N`` is
  never checked (nothing steps after it). The events that fired (time, output, value, entry) are in
  :class:`RunResult` and ``run.json`` (``"on_change"``).
* Recording. The first row is at ``start`` after initialization; then one row
  after each tick that reaches a multiple of ``output_interval``, holding every
  recorded variable as left by its instance's latest step (for a slower instance:
  the step covering that time).
* Stopping. A doStep returning Discard/Error/Fatal raises :class:`SimulationError`
  (instance, time, status) after the rows so far are written and ``run.json``
  says ``failed: ...``. Ctrl-C (SIGINT), SIGTERM or SIGHUP (main thread only; from the
  start of the setup to the final ``run.json``) or ``should_stop(t)`` returning True at an
  output row ends the run after the current tick with status ``interrupted`` (``run.json``'s
  ``"signal"`` names the signal); a second signal raises ``KeyboardInterrupt`` at once (rows so
  far are still written). An FMI 3 FMU asking to terminate ends the run as ``terminated: ...``.
  A file that cannot be written ends the run with ``ResultsWriteError`` naming it
  (``run.json``: ``failed: cannot write ...``).

Two implementations of this loop give bit-identical results (same FMI calls in the same order,
same arithmetic): the Python loop below, the reference, and the compiled fast path
(:mod:`milling_twin.orchestrator.fastpath`, the C library in ``fmus/stepper/``), which runs chunks of ticks
without returning to Python (keeping the coarse intervals' state in its plan, so a chunk may end inside
one). The compiled loop reads the watched outputs too and returns at a tick where an ``[[on_change]]``
entry fires, before anything of that tick; Python applies the entries and resumes at the same tick (one
return per event). ``run(stepping="auto")`` takes the fast path when its library is found
and the scenario is supported, else the Python path; the choice and its reason are in
:class:`RunResult` and ``run.json``. On the fast path Ctrl-C ends the run after the current chunk
(chunks last about 0.1 s) instead of the current tick; ``should_stop`` is still asked after
every output row and stops after that tick, as on the Python path.
"""
from __future__ import annotations

import copy
import ctypes
import logging
import math
import shutil
import signal
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from fmpy.fmi1 import FMICallException, printLogMessage
from fmpy.fmi2 import (defaultCallbacks, fmi2Boolean, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE, fmi2Integer,
                       fmi2Real, fmi2ValueReference)
from fmpy.fmi3 import fmi3Boolean, fmi3Float64, fmi3Int32, fmi3ValueReference
from fmpy.logging import addLoggerProxy
from tqdm import tqdm

from milling_twin.orchestrator import fastpath, fmu_cache
from milling_twin.orchestrator.fmu_loading import FMU2Slave, FMU3Slave
from milling_twin.orchestrator.results import RunFolder, RunWriter, sha256_of
from milling_twin.orchestrator.safe_names import check_name
from milling_twin.orchestrator.scenario import FmuInstance, Scenario

__all__ = ["FiredEvent", "RunResult", "SimulationError", "run"]

BLOCK_TICKS = 4096  # recorded inputs are sampled for this many ticks at a time
_log = logging.getLogger(__name__)
_STATUS = ["OK", "Warning", "Discard", "Error", "Fatal", "Pending"]
# fmpy's own FMI 2 logger, the target of its native logger proxy until a run points the proxy at the run's
# callback; made once (ctypes keeps a callback alive only as long as this object)
_FMPY_FMI2_LOGGER = fmi2CallbackLoggerTYPE(printLogMessage)


def _restore_fmpy_fmi2_logger() -> None:
    """Point fmpy's logger proxy back at fmpy's own logger. The proxy has one process-wide target, the
    logger installed last: left at a finished run's callback, which is freed with the run, it would crash
    the next FMI 2 FMU on fmpy's default callbacks that logs a message."""
    callbacks = fmi2CallbackFunctions()
    callbacks.logger = _FMPY_FMI2_LOGGER
    addLoggerProxy(ctypes.byref(callbacks))


class SimulationError(RuntimeError):
    """An FMI call failed; names the instance, the time, the function and the FMI status. ``run_dir``: the run
    folder with the rows written before the failure; ``process_report``: a whole-part run's per-block report of
    those rows (``milling_twin.simulate`` writes it), None otherwise."""

    run_dir: Any = None
    process_report: Any = None

    def __init__(self, instance: str, t: float, status: str, function: str = "doStep",
                 messages: Sequence[str] = ()) -> None:
        self.instance, self.time, self.status, self.function = instance, t, status, function
        detail = f": {' / '.join(messages)}" if messages else ""
        super().__init__(f"{function} of instance {instance!r} at t = {t!r} s returned {status}{detail}")

    @classmethod
    def from_call(cls, exc: FMICallException, instance: str, t: float,
                  messages: Sequence[str]) -> "SimulationError":
        status = _STATUS[exc.status] if 0 <= exc.status < len(_STATUS) else f"status {exc.status}"
        return cls(instance, t, status, exc.function.removeprefix("fmi2").removeprefix("fmi3"), messages)


@dataclass(frozen=True)
class FiredEvent:
    """An ``[[on_change]]`` entry that fired: at ``time``, before any instance stepped from there, ``output``
    had changed to ``value``; ``entry`` is its index in the scenario's ``on_change``."""

    time: float
    output: str
    value: int | bool
    entry: int


@dataclass(frozen=True)
class RunResult:
    status: str  # "completed", "interrupted", "terminated: ..."
    run_dir: Path
    steps: int  # base-grid ticks done
    fmu_steps: int  # doStep calls
    rows: int
    end_time: float
    wall_time: float  # setup, stepping and writing
    loop_wall_time: float  # stepping only
    steps_per_second: float  # steps / loop_wall_time
    stepping: str = "python"  # "fast" (compiled loop) or "python"
    stepping_reason: str = ""  # why the Python path was used ("" on the fast path)
    fine_intervals: int = 0  # [stepping]: coarse intervals evaluated fine (0 without [stepping])
    coarse_intervals: int = 0  # [stepping]: coarse intervals evaluated coarse (0 without [stepping])
    events: tuple[FiredEvent, ...] = ()  # [[on_change]]: the entries that fired, in order
    signal: str | None = None  # the signal (SIGINT, SIGTERM, SIGHUP) that stopped the run, if one did


class _Slave:
    """One FMU instance with its value-reference and value buffers built once."""

    def __init__(self, inst: FmuInstance, unzip_dir: str, scenario: Scenario,
                 fmi2_loggers: dict[bytes, Callable[[int, bytes | None], None]],
                 fmi_call_logger: Callable[[str], None] | None = None) -> None:
        self.inst, self.name, self.m = inst, inst.name, inst.ticks_per_step
        fmi3 = inst.fmi_version == 3
        vr_t, real_t, bool_t, int_t = ((fmi3ValueReference, fmi3Float64, fmi3Boolean, fmi3Int32) if fmi3
                                       else (fmi2ValueReference, fmi2Real, fmi2Boolean, fmi2Integer))
        cls = FMU3Slave if fmi3 else FMU2Slave
        fmu = cls(guid=inst.instantiation_token, unzipDirectory=unzip_dir,
                  modelIdentifier=inst.model_identifier, instanceName=inst.name, fmiCallLogger=fmi_call_logger)
        self.log_all = fmi_call_logger is not None  # FMI logging: the FMU's OK messages are logged too
        self.fmu, self.fmi3 = fmu, fmi3
        self.errors: deque[str] = deque(maxlen=3)  # the FMU's latest Discard/Error messages
        try:
            if fmi3:
                fmu.instantiate(logMessage=lambda env, status, category, message: self._log(status, message))
            else:
                # fmpy's native proxy formats the printf-style arguments before calling us, but it
                # keeps only the logger installed last: route each message by its instance name.
                fmi2_loggers[inst.name.encode()] = self._log
                self._callbacks = fmi2CallbackFunctions()
                self._callbacks.logger = fmi2CallbackLoggerTYPE(
                    lambda env, name, status, category, message:
                        fmi2_loggers.get(name or b"", self._log)(status, message))
                self._callbacks.allocateMemory = defaultCallbacks.allocateMemory
                self._callbacks.freeMemory = defaultCallbacks.freeMemory
                addLoggerProxy(ctypes.byref(self._callbacks))
                fmu.instantiate(callbacks=self._callbacks)
        except Exception as exc:  # fmpy raises a bare Exception when instantiate returns NULL
            fmu.freeLibrary()
            raise SimulationError(inst.name, scenario.start_time, "NULL", "instantiate", list(self.errors)) from exc

        def vrs(names: list[str]) -> Any:
            return _value_references(inst, names, vr_t)

        def is_real(name: str) -> bool:
            return inst.variables[name].type == "real"

        # Inputs: recorded channels first, then connections, per type.
        mine = [i for i in scenario.inputs if i.target.instance == inst.name]
        conns = [c for c in scenario.connections if c.target.instance == inst.name]
        self.rec_real = [i for i in mine if is_real(i.target.variable)]
        self.rec_bool = [i for i in mine if not is_real(i.target.variable)]
        self.conn_real = [c for c in conns if is_real(c.target.variable)]
        self.conn_bool = [c for c in conns if not is_real(c.target.variable)]
        real_in = [x.target.variable for x in self.rec_real + self.conn_real]
        bool_in = [x.target.variable for x in self.rec_bool + self.conn_bool]
        # Outputs: what connections and [stepping] read, what [[on_change]] watches, and what is recorded.
        wanted = [c.source.variable for c in scenario.connections if c.source.instance == inst.name]
        stepping = scenario.stepping
        # [stepping]: gate outputs are read after each step, as connection sources are
        wanted += [g.output.variable for g in (stepping.fine_when if stepping else ())
                   if g.output.instance == inst.name]
        # [[on_change]]: the watched outputs too
        wanted += [e.output.variable for e in scenario.on_change if e.output.instance == inst.name]
        self.variable = stepping is not None and inst.name in stepping.variable
        self.feeds_connections = bool(wanted)
        wanted += [r.variable for r in scenario.outputs if r.instance == inst.name]
        wanted = _whole_arrays(inst, list(dict.fromkeys(wanted)))
        real_out = [n for n in wanted if is_real(n)]
        bool_out = [n for n in wanted if inst.variables[n].type == "bool"]
        int_out = [n for n in wanted if inst.variables[n].type == "int"]
        self.out_index = {n: ("real", i) for i, n in enumerate(real_out)}
        self.out_index.update({n: ("bool", i) for i, n in enumerate(bool_out)})
        self.out_index.update({n: ("int", i) for i, n in enumerate(int_out)})

        self.vr_real_in, self.vr_bool_in = vrs(real_in), vrs(bool_in)
        self.vr_real_out, self.vr_bool_out, self.vr_int_out = vrs(real_out), vrs(bool_out), vrs(int_out)
        self.real_in, self.bool_in = (real_t * len(real_in))(), (bool_t * len(bool_in))()
        self.real_out, self.bool_out = (real_t * len(real_out))(), (bool_t * len(bool_out))()
        self.real_prev, self.bool_prev = (real_t * len(real_out))(), (bool_t * len(bool_out))()
        self.int_out = (int_t * len(int_out))()
        self.n_rec_real, self.n_rec_bool = len(self.rec_real), len(self.rec_bool)
        self.rec_real_rows: list = []
        self.rec_bool_rows: list = []
        self.conn_real_ops: list[tuple[int, Any, int, float]] = []  # filled by _wire
        self.conn_bool_ops: list[tuple[int, Any, int]] = []

        c = fmu.component
        set_r, set_b, get_r, get_b, get_i = ((fmu.fmi3SetFloat64, fmu.fmi3SetBoolean, fmu.fmi3GetFloat64,
                                              fmu.fmi3GetBoolean, fmu.fmi3GetInt32) if fmi3 else
                                             (fmu.fmi2SetReal, fmu.fmi2SetBoolean, fmu.fmi2GetReal,
                                              fmu.fmi2GetBoolean, fmu.fmi2GetInteger))
        extra = (lambda n: (n,)) if fmi3 else (lambda n: ())  # FMI 3 repeats the value count
        calls_in, calls_out = [], []
        for fn, vr, buf, calls in ((set_r, self.vr_real_in, self.real_in, calls_in),
                                   (set_b, self.vr_bool_in, self.bool_in, calls_in),
                                   (get_r, self.vr_real_out, self.real_out, calls_out),
                                   (get_b, self.vr_bool_out, self.bool_out, calls_out),
                                   (get_i, self.vr_int_out, self.int_out, calls_out)):
            if len(vr):
                calls.append(partial(fn, c, vr, len(vr), buf, *extra(len(buf))))  # FMI 3 arrays: all elements
        self._set_calls, self._get_calls = tuple(calls_in), tuple(calls_out)
        if fmi3:
            flags = [ctypes.c_bool() for _ in range(3)] + [fmi3Float64()]
            refs = [ctypes.byref(f) for f in flags]
            terminate = flags[1]

            def do_step(t: float, h: float) -> bool:
                fmu.fmi3DoStep(c, t, h, True, *refs)
                return terminate.value
        else:
            def do_step(t: float, h: float) -> bool:
                fmu.fmi2DoStep(c, t, h, True)
                return False
        self.do_step = do_step

    def _log(self, status: int, message: bytes | None) -> None:
        text = (message or b"").decode("utf-8", errors="replace").strip()
        if status >= 2:
            self.errors.append(text)
        elif status == 1:
            _log.warning("%s: %s", self.name, text)
        elif self.log_all:
            _log.info("%s: %s", self.name, text)

    def _setter(self, kind: str) -> Callable[[list[int], list[Any]], None]:
        """fmpy's set function for values of ``kind`` ("real", "int", "bool", "string")."""
        fmu = self.fmu
        return {"real": fmu.setFloat64 if self.fmi3 else fmu.setReal,
                "int": fmu.setInt32 if self.fmi3 else fmu.setInteger,
                "bool": fmu.setBoolean, "string": fmu.setString}[kind]

    def set_parameters(self) -> None:
        """Parameters and constant inputs, as start values (before initialization)."""
        params = {**self.inst.parameters, **self.inst.inputs}
        kinds = {n: self.inst.variables[n].type for n in params}
        vr = lambda names: [self.inst.variables[n].value_reference for n in names]  # noqa: E731
        for kind in ("real", "int", "bool", "string"):
            names = [n for n in params if kinds[n] == kind]
            if names:
                self._setter(kind)(vr(names), [params[n] for n in names])

    def set_value(self, name: str, value: Any) -> None:
        """One parameter during the run (a tunable one: [[on_change]]), in one FMI set call."""
        var = self.inst.variables[name]
        self._setter(var.type)([var.value_reference], [value])

    def set_inputs(self) -> None:
        for call in self._set_calls:
            call()

    def get_outputs(self) -> None:
        for call in self._get_calls:
            call()

    def column(self, variable: str) -> tuple[Any, int]:
        """The output buffer holding ``variable`` and its index there."""
        kind, j = self.out_index[variable]
        return {"real": self.real_out, "bool": self.bool_out, "int": self.int_out}[kind], j

    def snapshot(self) -> None:
        ctypes.memmove(self.real_prev, self.real_out, ctypes.sizeof(self.real_out))
        ctypes.memmove(self.bool_prev, self.bool_out, ctypes.sizeof(self.bool_out))

    def load_block(self, scenario: Scenario, times: np.ndarray) -> None:
        """Sample this instance's recorded inputs at ``times`` (one row per tick). The fast path samples them in
        C with the same arithmetic (orchestrator.fastpath)."""
        rec = scenario.recorded
        if self.rec_real:
            self.rec_real_rows = np.column_stack([rec.at(i.channel, times, i.interpolation) * i.factor
                                                  for i in self.rec_real]).tolist()
        if self.rec_bool:
            self.rec_bool_rows = np.column_stack([rec.at(i.channel, times, i.interpolation)
                                                  for i in self.rec_bool]).tolist()

    def free(self) -> None:
        try:
            self.fmu.terminate()
        finally:
            self.fmu.freeInstance()


def _whole_arrays(inst: FmuInstance, names: list[str]) -> list[str]:
    """``names`` with each element of an FMI 3 array replaced, where the array first appears, by all its
    elements in order: FMI 3 gets an array whole (one value reference, all its values)."""
    out: list[str] = []
    for name in names:
        array = inst.variables[name].array
        out += list(inst.variables[array].elements) if array else [name]
    return list(dict.fromkeys(out))


def _value_references(inst: FmuInstance, names: list[str], vr_type: Any) -> Any:
    """The value references of ``names`` (one per value buffer slot), except that the elements of an FMI 3
    array, which must follow each other completely and in order, are its one value reference."""
    refs: list[int] = []
    i = 0
    while i < len(names):
        var = inst.variables[names[i]]
        if var.array:
            elements = inst.variables[var.array].elements
            if tuple(names[i:i + len(elements)]) != elements:
                raise ValueError(f"instance {inst.name!r}: the elements of the FMI 3 array {var.array!r} must be "
                                 "set or read whole and in order")
            i += len(elements)
        else:
            i += 1
        refs.append(var.value_reference)
    return (vr_type * len(refs))(*refs)


def _wire(slaves: dict[str, _Slave], scenario: Scenario) -> None:
    """Give each slave its connection ops: (input position, source buffer, index[, factor])."""
    for s in slaves.values():
        for ops, conns, offset, real in ((s.conn_real_ops, s.conn_real, s.n_rec_real, True),
                                         (s.conn_bool_ops, s.conn_bool, s.n_rec_bool, False)):
            for pos, c in enumerate(conns, start=offset):
                src = slaves[c.source.instance]
                kind, j = src.out_index[c.source.variable]
                buf = ((src.real_prev if c.delay else src.real_out) if real else
                       (src.bool_prev if c.delay else src.bool_out))
                ops.append((pos, buf, j, c.factor) if real else (pos, buf, j))


def _feed(s: _Slave, row: int) -> None:
    if s.n_rec_real:
        s.real_in[: s.n_rec_real] = s.rec_real_rows[row]
    if s.n_rec_bool:
        s.bool_in[: s.n_rec_bool] = s.rec_bool_rows[row]
    for pos, buf, j, factor in s.conn_real_ops:
        s.real_in[pos] = buf[j] * factor
    for pos, buf, j in s.conn_bool_ops:
        s.bool_in[pos] = buf[j]
    s.set_inputs()


def _run_info(scenario: Scenario, fmu_hashes: dict[Path, str]) -> dict[str, Any]:
    rec = scenario.recorded
    return {
        "scenario": {"name": scenario.name, "path": str(scenario.path.resolve()),
                     "sha256": sha256_of(scenario.path)},
        "recorded": None if rec is None else {"path": str(rec.path.resolve()), "sha256": sha256_of(rec.path)},
        "fmus": [{"instance": i.name, "path": str(i.path.resolve()), "sha256": fmu_hashes[i.path],
                  "fmi_version": i.fmi_version, "model_identifier": i.model_identifier,
                  "instantiation_token": i.instantiation_token, "step_size": i.step_size,
                  "parameters": dict(i.parameters), "inputs": dict(i.inputs)} for i in scenario.instances],
        "execution_order": list(scenario.execution_order),
        "start_time": scenario.start_time, "stop_time": scenario.stop_time,
        "output_interval": scenario.output_interval, "base_step": scenario.base_step,
    }


def _stepping_settings(scenario: Scenario) -> dict[str, Any]:
    """``[stepping]`` as run.json records it (without the counts); {} without it."""
    st = scenario.stepping
    if st is None:
        return {}
    return {"coarse_step": st.coarse_step, "ticks_per_interval": st.ticks_per_interval,
            "variable": list(st.variable),
            "fine_when": [{"output": str(g.output), g.sense: bool(g.threshold) if g.sense == "is" else g.threshold}
                          for g in st.fine_when],
            "hold_intervals": st.hold_intervals}


class _Intervals:
    """The variable communication step's state from tick to tick on the Python path (the fast path keeps the
    same in its plan): whether the current coarse interval is fine, how many evaluations after the latest one
    stay fine because a condition held (``hold_left``), the counts, and the doSteps of the variable instances."""

    def __init__(self, scenario: Scenario, slaves: dict[str, _Slave]) -> None:
        st = scenario.stepping
        assert st is not None
        self.m = st.ticks_per_interval
        self.first = slaves[st.variable[0]]  # variable names are in execution order
        self.gates = [(slaves[g.output.instance].column(g.output.variable), g) for g in st.fine_when]
        self.hold = st.hold_intervals
        self.fine, self.hold_left = True, 0
        self.fine_count = self.coarse_count = self.steps = 0

    def evaluate(self) -> None:
        now = any(g.holds(buf[j]) for (buf, j), g in self.gates)
        self.fine = now or self.hold_left > 0
        self.hold_left = self.hold if now else max(self.hold_left - 1, 0)
        if self.fine:
            self.fine_count += 1
        else:
            self.coarse_count += 1


class _Triggers:
    """``[[on_change]]`` on both paths: each entry's output (its buffer element, read after every step of its
    instance), its value at the previous communication point of that instance (``last``), and the check. The fast
    path keeps ``last`` in its plan while C runs; at a tick where C found an entry firing, the master loads it from
    there, checks the tick here and stores it back."""

    def __init__(self, scenario: Scenario, slaves: dict[str, _Slave]) -> None:
        self.entries = []
        for entry in scenario.on_change:
            s = slaves[entry.output.instance]
            buf, j = s.column(entry.output.variable)
            targets = tuple((slaves[r.instance], r.variable, value) for r, value in entry.values)
            self.entries.append((buf, j, scenario.variable(entry.output).type == "bool", s.m, entry, targets))
        self.last = [self._value(i) for i in range(len(self.entries))]  # after initialization
        self.fired: list[FiredEvent] = []

    def _value(self, i: int) -> int:
        buf, j, boolean = self.entries[i][:3]
        return int(buf[j] != 0) if boolean else int(buf[j])  # as the stepper reads it

    def check(self, tick: int) -> list[int]:
        """The entries firing at ``tick`` (file order); each entry due there remembers its output's value."""
        firing = []
        for i, (_, _, _, m, entry, _) in enumerate(self.entries):
            if tick % m == 0:
                value = self._value(i)
                if value != self.last[i]:
                    self.last[i] = value
                    if value == entry.equals:
                        firing.append(i)
        return firing


class _Writer(RunWriter):
    """RunWriter with, for the fast path, block appends (the same buffer and flush rules as append)
    and chunk files written by a worker thread (:meth:`in_background`): Parquet encoding and fsync
    then overlap the C stepping, which runs without the GIL. One chunk is in flight at a time, so
    chunks still reach the disk complete and in order; ``rows_written`` counts rows on disk; an
    error of the worker is raised by the next flush or by finish."""

    _pool: ThreadPoolExecutor | None = None
    _in_flight: Future | None = None
    _sink: RunWriter | None = None
    _spare: np.ndarray | None = None

    def in_background(self) -> None:
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="chunk-writer")
        self._spare = np.empty_like(self._buffer)

    def append_rows(self, rows: np.ndarray) -> None:
        done = 0
        while done < len(rows):
            n = min(len(rows) - done, len(self._buffer) - self._fill)
            self._buffer[self._fill:self._fill + n] = rows[done:done + n]
            self._fill += n
            done += n
            if self._fill == len(self._buffer) or time.monotonic() - self._last_flush >= self._flush_seconds:
                self.flush()

    def flush(self) -> None:
        if self._pool is None:
            super().flush()
            return
        self._last_flush = time.monotonic()
        if self._fill == 0:
            return
        self.wait()  # the previous chunk is on disk and its buffer free
        sink = copy.copy(self)  # RunWriter.flush on a copy that owns the full buffer
        self._buffer, self._spare, self._fill = self._spare, self._buffer, 0
        self._sink, self._in_flight = sink, self._pool.submit(RunWriter.flush, sink)

    def wait(self) -> None:
        if self._in_flight is not None:
            future, self._in_flight = self._in_flight, None
            future.result()
            self.chunks, self.rows_written = self._sink.chunks, self._sink.rows_written

    def finish(self, status: str, **extra: Any) -> None:
        # the chunk in flight first; the rest is written here, as the caller waits for it anyway (a short run
        # then never starts the worker thread). A chunk the worker could not write fails the run, which
        # run.json then says.
        error: OSError | None = None
        if self._pool is not None:
            try:
                self.wait()
            except OSError as exc:
                self._in_flight = None
                if not status.startswith("failed"):
                    error, status = exc, f"failed: {exc}"
            finally:
                self._pool.shutdown()
                self._pool = None
        super().finish(status, **extra)
        if error is not None:
            raise error


# the signals that end a run like Ctrl-C (SIGHUP: not on Windows)
_STOP_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))


class _StopFlag:
    """Set by the first SIGINT (Ctrl-C), SIGTERM or SIGHUP, whose name goes to ``signal``; a second one raises
    ``KeyboardInterrupt`` at once. Installed in the main thread only; a signal the process ignores (SIG_IGN,
    e.g. SIGHUP under nohup) stays ignored. The previous handlers are restored at exit."""

    def __init__(self) -> None:
        self.set = False
        self.signal: str | None = None
        self._previous: dict[int, Any] = {}

    def __enter__(self) -> "_StopFlag":
        if threading.current_thread() is threading.main_thread():
            for signum in _STOP_SIGNALS:
                if signal.getsignal(signum) is signal.SIG_IGN:
                    continue
                self._previous[signum] = signal.signal(signum, self._handle)
        return self

    def _handle(self, signum: int, frame: Any) -> None:
        if self.signal is not None:
            raise KeyboardInterrupt(f"{signal.Signals(signum).name} while stopping")
        self.set = True
        self.signal = signal.Signals(signum).name

    def __exit__(self, *exc: object) -> None:
        for signum, previous in self._previous.items():
            # None: a handler not installed from Python; Python's default is the best stand-in
            default = signal.default_int_handler if signum == signal.SIGINT else signal.SIG_DFL
            signal.signal(signum, previous if previous is not None else default)
        self._previous.clear()


class _Run:
    """The state of one run; ``run()`` is the public entry point."""

    def __init__(self, scenario: Scenario, writer: RunWriter, fmu_hashes: dict[Path, str],
                 fmi_call_logger: Callable[[str], None] | None = None) -> None:
        self.fmi_call_logger = fmi_call_logger
        self.scenario, self.writer, self.fmu_hashes = scenario, writer, fmu_hashes
        self.base, self.start = scenario.base_step, scenario.start_time
        self.n_ticks = math.floor((scenario.stop_time - self.start) / scenario.output_interval
                                  + 1e-9) * scenario.ticks_per_output
        self.unzip_dirs: dict[Path, fmu_cache.Unpacked] = {}
        self.slaves: dict[str, _Slave] = {}
        self.fmi2_loggers: dict[bytes, Callable[[int, bytes | None], None]] = {}
        self.tick = 0
        self.current = ""  # instance of the FMI call in progress, for error messages
        self.t = self.start
        self.status = "completed"
        self.loop_wall = 0.0
        self.intervals: _Intervals | None = None  # [stepping] (the Python path's state)
        self.triggers: _Triggers | None = None  # [[on_change]]
        self.counts = (0, 0, 0)  # [stepping]: fine intervals, coarse intervals, doSteps of variable instances

    def grid(self, k: Any) -> Any:
        return self.start + k * self.base  # exact multiples: no drift over long runs

    def setup(self) -> None:
        scenario, start = self.scenario, self.start
        for inst in scenario.instances:
            self.current = inst.name
            if inst.path not in self.unzip_dirs:
                self.unzip_dirs[inst.path] = fmu_cache.unpack(inst.path, self.fmu_hashes[inst.path])
            self.slaves[inst.name] = _Slave(inst, self.unzip_dirs[inst.path].folder, scenario, self.fmi2_loggers,
                                          self.fmi_call_logger)
            self.slaves[inst.name].set_parameters()
        _wire(self.slaves, scenario)
        if scenario.stepping is not None:
            self.intervals = _Intervals(scenario, self.slaves)
        order = list(self.slaves.values())
        for s in order:
            self.current = s.name
            if s.fmi3:
                s.fmu.enterInitializationMode(startTime=start)
            else:
                s.fmu.setupExperiment(startTime=start)
                s.fmu.enterInitializationMode()
        for s in order:
            self.current = s.name
            s.load_block(scenario, np.array([start]))
            _feed(s, 0)
            s.get_outputs()
        for s in order:
            self.current = s.name
            s.fmu.exitInitializationMode()
            s.get_outputs()
            s.snapshot()
        if scenario.on_change:
            self.triggers = _Triggers(scenario, self.slaves)

    def fire(self, firing: Sequence[int], t: float) -> None:
        """Apply the ``[[on_change]]`` entries ``firing`` at ``t``: their values, in file and written order."""
        triggers = self.triggers
        assert triggers is not None
        for i in firing:
            entry, targets = triggers.entries[i][4:]
            for slave, name, value in targets:
                self.current = slave.name
                slave.set_value(name, value)
            triggers.fired.append(FiredEvent(t, str(entry.output), entry.equals, i))

    def loop(self, stop: _StopFlag, bar: tqdm, should_stop: Callable[[float], bool] | None) -> None:
        scenario, n_ticks, tpo, grid = self.scenario, self.n_ticks, self.scenario.ticks_per_output, self.grid
        order = list(self.slaves.values())
        delayed = [self.slaves[n] for n in dict.fromkeys(
            c.source.instance for c in scenario.connections if c.delay)]
        recorders = [s for s in order if s.out_index]
        record = [self.slaves[r.instance].column(r.variable) for r in scenario.outputs]
        append = self.writer.append
        append([self.start] + [buf[j] for buf, j in record])
        iv = self.intervals
        gate_point, coarse = (iv.first, iv.m) if iv is not None else (None, 0)
        triggers = self.triggers

        tick = 0
        try:
            while tick < n_ticks and not stop.set:
                row = tick % BLOCK_TICKS
                if row == 0:
                    bar.update(tick - bar.n)
                    times = grid(np.arange(tick, min(tick + BLOCK_TICKS, n_ticks)))
                    for s in order:
                        s.load_block(scenario, times)
                t = self.t = grid(tick)
                if triggers is not None:
                    firing = triggers.check(tick)
                    if firing:
                        self.fire(firing, t)
                for s in delayed:
                    s.snapshot()
                for s in order:
                    if s is gate_point and tick % coarse == 0:
                        iv.evaluate()
                    m = coarse if s.variable and not iv.fine else s.m
                    if tick % m:
                        continue
                    self.current = s.name
                    _feed(s, row)
                    if s.do_step(t, grid(min(tick + m, n_ticks)) - t):
                        self.status = f"terminated: instance {s.name!r} asked to terminate at t = {t!r} s"
                        stop.set = True
                    if s.variable:
                        iv.steps += 1
                    if s.feeds_connections:
                        s.get_outputs()
                tick += 1
                if tick % tpo == 0:
                    t = self.t = grid(tick)
                    for s in recorders:
                        self.current = s.name
                        s.get_outputs()
                    append([t] + [buf[j] for buf, j in record])
                    if should_stop is not None and should_stop(t):
                        stop.set = True
        finally:
            self.tick = tick
            if iv is not None:
                self.counts = (iv.fine_count, iv.coarse_count, iv.steps)
            bar.update(tick - bar.n)
        if stop.set and self.status == "completed":
            self.status = "interrupted"

    def fast_loop(self, stop: _StopFlag, bar: tqdm, should_stop: Callable[[float], bool] | None,
                  library: ctypes.CDLL) -> None:
        """The loop above in C, a chunk of ticks per call (see orchestrator.fastpath)."""
        scenario, n_ticks = self.scenario, self.n_ticks
        record = [self.slaves[r.instance].column(r.variable) for r in scenario.outputs]
        stepper = fastpath.Stepper(library, list(self.slaves.values()), scenario, n_ticks, record, should_stop)
        stepper.stop_requested = lambda: stop.set
        self.writer.append([self.start] + [buf[j] for buf, j in record])
        self.writer.in_background()
        tick, chunk = 0, fastpath.FIRST_CHUNK_TICKS
        triggers = self.triggers
        if triggers is not None:
            stepper.remember(triggers.last)
        try:
            while tick < n_ticks and not stop.set:
                self.t = self.grid(tick)
                last, elapsed = min(tick + chunk, n_ticks), 0.0
                while True:  # the chunk, resumed after each [[on_change]] event at the tick C stopped at
                    t0 = time.perf_counter()
                    out = stepper.run_chunk(tick, last)
                    elapsed += time.perf_counter() - t0
                    tick = out.tick
                    self.writer.append_rows(out.rows)
                    if out.code != fastpath.EVENT or triggers is None:
                        break
                    self.t = out.time
                    triggers.last = stepper.remembered()
                    firing = triggers.check(tick)
                    if not firing:  # C and Python disagree: resuming would stop at the same tick again
                        raise RuntimeError(f"the stepper stopped for an [[on_change]] event at t = {out.time!r} s, "
                                           "but no entry fires there")
                    self.fire(firing, out.time)
                    stepper.remember(triggers.last)
                bar.update(tick - bar.n)
                if stepper.pending is not None:
                    raise stepper.pending
                if out.code == fastpath.FAILED:
                    self.current, self.t = out.instance, out.time
                    raise FMICallException(function=out.function, status=out.status)
                if out.code == fastpath.OUT_OF_RECORDING:
                    self.current, self.t = out.instance, out.time
                    stepper.raise_out_of_recording(out)
                if out.code == fastpath.TERMINATED:
                    self.status = f"terminated: instance {out.instance!r} asked to terminate at t = {out.time!r} s"
                    stop.set = True
                elif out.code == fastpath.STOPPED:
                    stop.set = True
                if elapsed > 0:  # aim at CHUNK_SECONDS per chunk, changing by at most 4x at a time
                    chunk = round(min(max(chunk * fastpath.CHUNK_SECONDS / elapsed, chunk / 4), chunk * 4))
                chunk = max(1, min(chunk, stepper.max_ticks()))
        finally:
            self.tick = tick
            self.counts = stepper.interval_counts()
            bar.update(tick - bar.n)
        if stop.set and self.status == "completed":
            self.status = "interrupted"

    def fmu_steps(self) -> int:
        """doStep calls so far: each instance's due ticks, except the counted steps of variable instances."""
        return sum(-(-self.tick // s.m) for s in self.slaves.values() if not s.variable) + self.counts[2]

    def close(self) -> None:
        for s in self.slaves.values():
            try:
                s.free()
            except Exception:  # a failed FMU may refuse to terminate; free the others anyway
                pass
        if self.fmi2_loggers:
            _restore_fmpy_fmi2_logger()
        for d in self.unzip_dirs.values():
            if d.temporary:
                shutil.rmtree(d.folder, ignore_errors=True)


def run(scenario: Scenario, out_dir: str | Path, *, progress: bool = True,
        should_stop: Callable[[float], bool] | None = None, flush_rows: int = 10_000,
        flush_seconds: float = 1.0, stepping: str = "auto",
        fmi_call_logger: Callable[[str], None] | None = None, if_busy: str = "refuse",
        folder: RunFolder | None = None) -> RunResult:
    """Co-simulate ``scenario``, writing results to ``out_dir/<scenario name>/``.

    The run owns that folder while it runs (:class:`~milling_twin.orchestrator.results.RunFolder`); when
    another run owns it, ``if_busy`` says what to do: "refuse" (raise ``RunFolderBusy``, before anything is
    written), "wait", or "new" (the first free ``<name>-2``, ``<name>-3``, ...; ``RunResult.run_dir`` says which).
    ``folder``: a folder the caller claimed already (and releases), used instead of ``out_dir/<name>``.
    ``should_stop(t)`` is asked after each output row; True ends the run like Ctrl-C; so do SIGTERM and SIGHUP
    (``RunResult.signal`` and ``run.json``'s ``"signal"`` name the signal that stopped the run).
    An ``OSError`` writing the results (disk full, ...) raises ``ResultsWriteError`` naming the file, after
    ``run.json`` says ``failed: <message>`` (when it can be written).
    ``stepping``: "auto" (the fast path when available, else Python), "fast" (raises
    :class:`milling_twin.orchestrator.fastpath.FastPathUnavailable`, before writing anything, when it cannot
    run) or "python".
    ``fmi_call_logger`` receives every FMI call as text (fmpy's call logging), and the FMUs' messages of
    every status go to this module's logger: the FMI calls are made from Python, so the python stepping loop
    runs ("fast" raises :class:`~milling_twin.orchestrator.fastpath.FastPathUnavailable`).
    Raises :class:`SimulationError` when an FMI call fails (results so far are kept).
    """
    if fmi_call_logger is not None:
        if stepping == "fast":
            raise fastpath.FastPathUnavailable("FMI call logging needs the python stepping loop (the compiled "
                                               "loop calls the FMUs from C): use --path auto or python")
        stepping = "python"
    choice = fastpath.choose(scenario, stepping)
    columns = ["time"] + [str(r) for r in scenario.outputs]
    bools = [str(r) for r in scenario.outputs if scenario.variable(r).type == "bool"]
    ints = [str(r) for r in scenario.outputs if scenario.variable(r).type == "int"]
    units = {"time": {"unit": "s"}} | {str(r): {"unit": v.unit, "display_unit": v.display_unit}
                                       for r, v in ((r, scenario.variable(r)) for r in scenario.outputs)}
    # each FMU file hashed once, for run.json and as the key of its unpacked folder (orchestrator.fmu_cache)
    fmu_hashes = {path: sha256_of(path) for path in dict.fromkeys(i.path for i in scenario.instances)}
    info = {**_run_info(scenario, fmu_hashes), "stepping": {
        "path": choice.path, "library": None if choice.library is None else str(choice.library),
        "reason": choice.reason}}
    if scenario.stepping is not None:  # the counts are added when the run ends
        info["stepping"]["variable_step"] = _stepping_settings(scenario)
    check_name(scenario.name, f"{scenario.path}: [scenario].name")
    owned = folder is None
    if folder is None:
        folder = RunFolder.claim(Path(out_dir) / scenario.name, if_busy)
    try:
        writer = _Writer(folder, columns, bools, info,
                         flush_rows=flush_rows, flush_seconds=flush_seconds, int_columns=ints, units=units)
    except BaseException:
        if owned:
            folder.release()
        raise
    try:
        return _run(scenario, writer, fmu_hashes, fmi_call_logger, choice, info, progress, should_stop)
    finally:
        if owned:
            folder.release()


def _run(scenario: Scenario, writer: _Writer, fmu_hashes: dict[Path, str],
         fmi_call_logger: Callable[[str], None] | None, choice: Any, info: dict[str, Any], progress: bool,
         should_stop: Callable[[float], bool] | None) -> RunResult:
    """The run of :func:`run` into the claimed folder of ``writer``."""
    state = _Run(scenario, writer, fmu_hashes, fmi_call_logger)
    t0_wall = time.perf_counter()
    wall = 0.0
    failure: BaseException | None = None
    with _StopFlag() as stop:  # through finish: a signal while the last rows are written waits for them
        try:
            try:
                state.setup()
                with tqdm(total=state.n_ticks, unit="step", unit_scale=True, delay=1.0,
                          disable=not progress, desc=scenario.name) as bar:
                    t0_loop = time.perf_counter()
                    try:
                        if choice.path == "fast":
                            state.fast_loop(stop, bar, should_stop, fastpath.load_library(choice.library))
                        else:
                            state.loop(stop, bar, should_stop)
                    finally:
                        state.loop_wall = time.perf_counter() - t0_loop
            except FMICallException as exc:
                slave = state.slaves.get(state.current)
                raise SimulationError.from_call(exc, state.current, state.t,
                                                list(slave.errors) if slave else []) from exc
        except BaseException as exc:
            failure = exc
            state.status = "interrupted" if isinstance(exc, KeyboardInterrupt) else f"failed: {exc}"
            raise
        finally:
            fmu_steps = state.fmu_steps()
            events = tuple(state.triggers.fired) if state.triggers is not None else ()
            on_change = {} if not scenario.on_change else {"on_change": {
                "entries": [e.table() for e in scenario.on_change],
                "events": [{"time": e.time, "output": e.output, "value": e.value, "entry": e.entry}
                           for e in events]}}
            rate = state.tick / state.loop_wall if state.loop_wall > 0 else 0.0
            wall = time.perf_counter() - t0_wall
            variable_step = {} if scenario.stepping is None else {"variable_step": {
                **_stepping_settings(scenario), "fine_intervals": state.counts[0],
                "coarse_intervals": state.counts[1]}}
            stopped_by = {} if stop.signal is None else {"signal": stop.signal}
            try:
                writer.finish(state.status, steps=state.tick, fmu_steps=fmu_steps,
                              end_time=state.grid(state.tick), wall_time=wall,
                              loop_wall_time=state.loop_wall, steps_per_second=rate,
                              stepping={**info["stepping"], **variable_step}, **on_change, **stopped_by)
            except OSError as exc:
                if failure is None:
                    raise
                _log.error("%s", exc)  # the run's own failure is the error raised
            finally:
                state.close()
    return RunResult(state.status, writer.run_dir, state.tick, fmu_steps, writer.rows_written,
                     state.grid(state.tick), wall, state.loop_wall, rate, choice.path, choice.reason,
                     state.counts[0], state.counts[1], events, stop.signal)
