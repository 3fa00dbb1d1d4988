"""The compiled stepping path: the master's inner loop in C (``fmus/stepper/``), driven through ctypes.

fmpy still does what it does well: extracting, loading and instantiating the FMUs, setting
parameters and initializing (``milling_twin.orchestrator.master`` does all of that once, for both paths). After
setup, :class:`Stepper` hands the C library (``libmilling_stepper.so``; ``.dylib`` on macOS, ``milling_stepper.dll``
on Windows: :data:`LIBRARY_NAME`) each instance's FMI function
pointers (taken from the library fmpy loaded) and component, the ctypes input and output buffers
the Python path itself uses, the connection table (as addresses of the source elements, with their
unit factors) and the recorded columns. ``stp_run`` then performs a chunk of ticks without
returning to Python, with the semantics of the Python loop in ``orchestrator/master.py``, call for
call, so the two paths give bit-identical results:

* Recorded inputs are sampled in C at each due step's time ``start + k * base``, with numpy's
  arithmetic (``fmus/stepper/recorded_sample.h``: ``np.interp`` or the held sample, clipped to the
  recording, then times the unit factor), so they equal the Python path's ``RecordedData.at``
  values; a time outside the recording ends the chunk and raises ``RecordedDataError`` here, as
  ``RecordedData.at`` raises it on the Python path.
* Connections compute ``source * factor`` (one IEEE multiplication, as Python does); booleans are
  converted as ctypes converts them (FMI 2: ``int``, FMI 3: ``bool``).
* Rows (time, then the recorded variables as float64) go into a numpy buffer; the master appends
  them to the results in one block per chunk.
* The variable communication step (``[stepping]``): the plan holds the conditions (the address of each gate
  output with its threshold and sense), each instance's ``variable`` flag, and the coarse intervals' state
  (current interval fine or coarse, how many evaluations stay fine because a condition held, the counts), which
  ``stp_run`` carries from one chunk to the next, so a chunk may end anywhere inside an interval.
* Parameter changes at events (``[[on_change]]``): the plan holds each entry's watched output (the address of its
  Int32 or Boolean element, read after every step of its instance, since it is among the outputs read there),
  its instance's step in ticks, the value that fires and the value at the previous check. At the start of a tick
  where an entry fires, ``stp_run`` returns :data:`EVENT` before doing anything of that tick, leaving the
  remembered values as they were; the master reads them (:meth:`Stepper.remembered`), checks the tick as the
  Python loop does, sets the parameters, stores the values back (:meth:`Stepper.remember`) and calls ``stp_run``
  again from that tick to the same end: C then finds nothing new there and steps on.

Chunks are sized to take about :data:`CHUNK_SECONDS` of wall time (they start small and adapt),
so the progress bar moves and Ctrl-C, which Python can only act on between chunks, stops the run
within about that time. ``should_stop`` is asked after every output row, as on the Python path,
through a callback from C (only when given). An FMI call returning Discard/Error/Fatal ends the
chunk and is reported back (instance, function, status, time) so the master raises the same
:class:`~orchestrator.master.SimulationError`, with the FMU's log messages, after writing the rows.

The library is found, in this order: ``$MILLING_TWIN_STEPPER`` (the path of the ``.so``; an empty
value or ``off`` disables the fast path), then ``stepper/libmilling_stepper.so`` next to the folder
of the scenario's FMUs (``build/stepper/`` beside ``build/fmus/``, ``milling_twin/stepper/`` beside an installed
wheel's ``milling_twin/fmus/``), then the repository's ``build/stepper/``, then the installed package's
``milling_twin/stepper/`` (:mod:`milling_twin.orchestrator.packaged`).
"""
from __future__ import annotations

import ctypes
import functools
import os
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from milling_twin.orchestrator.packaged import packaged_file
from milling_twin.orchestrator.scenario import Scenario

__all__ = ["LIBRARY_ENV", "LIBRARY_NAME", "Choice", "FastPathUnavailable", "Stepper", "choose",
           "find_library", "load_library", "unsupported"]

LIBRARY_ENV = "MILLING_TWIN_STEPPER"
# the stepper library's file on this system, as CMake and fmus/cross/build_all_platforms.py name it
LIBRARY_NAMES = {"win32": "milling_stepper.dll", "darwin": "libmilling_stepper.dylib"}
LIBRARY_NAME = LIBRARY_NAMES.get(sys.platform, "libmilling_stepper.so")
ABI_VERSION = 7
CHUNK_SECONDS = 0.1  # wall time a chunk should take: the Ctrl-C latency and progress-bar period
FIRST_CHUNK_TICKS = 256
MAX_CHUNK_TICKS = 1 << 18  # bounds a chunk where ticks cost next to nothing (and rows are rare)
MAX_CHUNK_ROWS = 1 << 14  # bounds the row buffer

_REPO_BUILD = Path(__file__).resolve().parents[1] / "build" / "stepper" / LIBRARY_NAME
REAL, BOOL_FMI2, BOOL_FMI3 = 0, 1, 2
DONE, STOPPED, TERMINATED, FAILED, OUT_OF_RECORDING, EVENT = 0, 1, 2, 3, 4, 5
# stp_outcome.function -> the FMI function's name without its fmi2/fmi3 prefix
_FUNCTIONS = {2: ["", "SetReal", "SetBoolean", "DoStep", "GetReal", "GetBoolean", "GetInteger"],
              3: ["", "SetFloat64", "SetBoolean", "DoStep", "GetFloat64", "GetBoolean", "GetInt32"]}

_vp, _i32, _i64, _f64 = ctypes.c_void_p, ctypes.c_int32, ctypes.c_int64, ctypes.c_double
STOP_CALLBACK = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_double)


class _Link(ctypes.Structure):
    _fields_ = [("source", _vp), ("factor", _f64), ("source_kind", _i32), ("position", _i32)]


class _Recorded(ctypes.Structure):
    _fields_ = [("values", _vp), ("factor", _f64), ("hint", _i64), ("linear", _i32), ("reserved", _i32)]


class _Gate(ctypes.Structure):
    _fields_ = [("source", _vp), ("threshold", _f64), ("kind", _i32), ("sense", _i32)]


_SENSES = {"above": 0, "below": 1, "is": 2}  # stp_gate.sense


class _Watch(ctypes.Structure):
    _fields_ = [("source", _vp), ("ticks_per_step", _i64), ("kind", _i32), ("boolean", _i32), ("equals", _i32),
                ("last", _i32)]


class _Column(ctypes.Structure):
    _fields_ = [("source", _vp), ("kind", _i32), ("reserved", _i32)]


class _Instance(ctypes.Structure):
    _fields_ = [("component", _vp),
                ("fmi2_set_real", _vp), ("fmi2_set_boolean", _vp), ("fmi2_get_real", _vp),
                ("fmi2_get_boolean", _vp), ("fmi2_do_step", _vp),
                ("fmi3_set_float64", _vp), ("fmi3_set_boolean", _vp), ("fmi3_get_float64", _vp),
                ("fmi3_get_boolean", _vp), ("fmi3_do_step", _vp),
                ("vr_real_in", _vp), ("vr_bool_in", _vp), ("real_in", _vp), ("bool_in", _vp),
                ("rec_real", _vp), ("rec_bool", _vp), ("real_links", _vp), ("bool_links", _vp),
                ("vr_real_out", _vp), ("vr_bool_out", _vp), ("real_out", _vp), ("real_prev", _vp),
                ("bool_out", _vp), ("bool_prev", _vp),
                ("n_real_in", _i64), ("n_bool_in", _i64), ("n_rec_real", _i64), ("n_rec_bool", _i64),
                ("n_real_links", _i64), ("n_bool_links", _i64), ("n_real_out", _i64), ("n_bool_out", _i64),
                ("fmi_version", _i32), ("ticks_per_step", _i32), ("get_after_step", _i32),
                ("snapshot", _i32), ("get_at_rows", _i32), ("variable", _i32),
                ("fmi2_get_integer", _vp), ("fmi3_get_int32", _vp), ("vr_int_out", _vp), ("int_out", _vp),
                ("n_int_out", _i64), ("n_vr_real_in", _i64), ("n_vr_bool_in", _i64), ("n_vr_real_out", _i64),
                ("n_vr_bool_out", _i64), ("n_vr_int_out", _i64)]


class _Plan(ctypes.Structure):
    _fields_ = [("start", _f64), ("base", _f64), ("n_ticks", _i64), ("ticks_per_output", _i64),
                ("n_instances", _i64), ("n_columns", _i64), ("instances", ctypes.POINTER(_Instance)),
                ("columns", ctypes.POINTER(_Column)), ("should_stop", STOP_CALLBACK),
                ("recorded_time", _vp), ("recorded_samples", _i64), ("recorded_tolerance", _f64),
                ("gates", ctypes.POINTER(_Gate)), ("n_gates", _i64), ("ticks_per_interval", _i64),
                ("first_variable", _i64), ("hold_intervals", _i64), ("fine_intervals", _i64),
                ("coarse_intervals", _i64), ("variable_steps", _i64), ("hold_left", _i64), ("fine", _i32),
                ("watches", ctypes.POINTER(_Watch)), ("n_watches", _i64)]


class _Outcome(ctypes.Structure):
    _fields_ = [("tick", _i64), ("rows", _i64), ("code", _i32), ("instance", _i32), ("function", _i32),
                ("status", _i32), ("time", _f64)]


class FastPathUnavailable(RuntimeError):
    """The fast path was requested explicitly but cannot run this scenario; says why."""


@dataclass(frozen=True)
class Choice:
    """Which stepping path a run uses: ``path`` "fast" or "python", the library (fast path) and
    ``reason``: why the Python path was used (empty for the fast path)."""

    path: str
    library: Path | None = None
    reason: str = ""


def find_library(scenario: Scenario) -> tuple[Path | None, str]:
    """The stepper library for ``scenario`` and, when none is found, where it was looked for."""
    env = os.environ.get(LIBRARY_ENV)
    if env is not None:
        if env.strip().lower() in ("", "off", "0", "none"):
            return None, f"disabled by ${LIBRARY_ENV}={env!r}"
        path = Path(env)
        return (path, "") if path.is_file() else (None, f"${LIBRARY_ENV} = {env}: no such file")
    packaged = packaged_file("stepper", LIBRARY_NAME)
    candidates = list(dict.fromkeys([inst.path.resolve().parent.parent / "stepper" / LIBRARY_NAME
                                     for inst in scenario.instances] + [_REPO_BUILD]
                                    + ([packaged] if packaged is not None else [])))
    for path in candidates:
        if path.is_file():
            return path, ""
    return None, (f"stepper library not found in {', '.join(str(p.parent) for p in candidates)} "
                  f"(build it with cmake, or set ${LIBRARY_ENV})")


@functools.lru_cache(maxsize=None)
def load_library(path: Path) -> ctypes.CDLL:
    """Load and check the stepper library; raises OSError when it is unusable."""
    lib = ctypes.CDLL(str(path))
    lib.stp_abi_version.restype = ctypes.c_int
    lib.stp_struct_size.restype = ctypes.c_size_t
    lib.stp_struct_size.argtypes = [ctypes.c_int]
    lib.stp_run.restype = None
    lib.stp_run.argtypes = [ctypes.POINTER(_Plan), _i64, _i64, _vp, ctypes.POINTER(_Outcome)]
    if lib.stp_abi_version() != ABI_VERSION:
        raise OSError(f"{path}: ABI version {lib.stp_abi_version()}, expected {ABI_VERSION}: rebuild it")
    for which, struct in enumerate((_Link, _Column, _Instance, _Plan, _Outcome, _Recorded, _Gate, _Watch)):
        if lib.stp_struct_size(which) != ctypes.sizeof(struct):
            raise OSError(f"{path}: {struct.__name__.lstrip('_')} has {lib.stp_struct_size(which)} bytes, "
                          f"expected {ctypes.sizeof(struct)}: rebuild it")
    return lib


def unsupported(scenario: Scenario) -> str:
    """Why the fast path cannot run ``scenario`` ("" when it can)."""
    for inst in scenario.instances:
        if inst.fmi_version not in (2, 3):
            return f"instance {inst.name!r} is FMI {inst.fmi_version}"
    refs = ([i.target for i in scenario.inputs] + [c.source for c in scenario.connections]
            + [c.target for c in scenario.connections])
    for ref, kinds in [(r, ("real", "bool")) for r in refs] + [(r, ("real", "bool", "int")) for r in scenario.outputs]:
        kind = scenario.variable(ref).type
        if kind not in kinds:
            return f"{ref} has type {kind}"
    rec = scenario.recorded
    for i in scenario.inputs:
        if scenario.variable(i.target).type == "bool" and rec.channels[i.channel].dtype != np.bool_:
            return f"boolean input {i.target} is fed by the non-boolean channel {i.channel!r}"
    return ""


def choose(scenario: Scenario, requested: str = "auto") -> Choice:
    """The path for ``requested`` "auto", "fast" or "python"; "fast" raises
    :class:`FastPathUnavailable` when the fast path cannot run."""
    if requested not in ("auto", "fast", "python"):
        raise ValueError(f"stepping must be 'auto', 'fast' or 'python', got {requested!r}")
    if requested == "python":
        return Choice("python", reason="requested")
    path, reason = find_library(scenario)
    if path is not None:
        try:
            load_library(path.resolve())
        except OSError as exc:
            path, reason = None, f"stepper library unusable: {exc}"
    if path is not None:
        reason = unsupported(scenario)
        if reason:
            reason = f"not supported by the fast path: {reason}"
    if reason:
        if requested == "fast":
            raise FastPathUnavailable(f"the fast path cannot run scenario {scenario.name!r}: {reason}")
        return Choice("python", reason=reason)
    return Choice("fast", library=path.resolve())


def _address(buffer: Any, index: int = 0) -> int:
    return ctypes.addressof(buffer) + index * ctypes.sizeof(buffer._type_)


def _kind(buffer: Any) -> int:
    """The element kind; an int element (fmi2Boolean, fmi2Integer, fmi3Int32) is BOOL_FMI2, read as is."""
    return REAL if buffer._type_ is ctypes.c_double else (
        BOOL_FMI3 if buffer._type_ is ctypes.c_bool else BOOL_FMI2)


@dataclass
class Outcome:
    code: int  # DONE, STOPPED, TERMINATED, FAILED, OUT_OF_RECORDING, EVENT
    tick: int  # ticks completed (EVENT: the tick where an [[on_change]] entry fires, not begun)
    rows: np.ndarray  # the rows written (a view of the stepper's buffer, valid until the next chunk)
    instance: str  # failing or terminating instance, else ""
    function: str  # the failing FMI function, e.g. "fmi2DoStep"
    status: int
    time: float  # EVENT: the time of that tick


class Stepper:
    """Runs chunks of ticks of one set-up co-simulation in C.

    ``slaves``: the master's instances in execution order, each with (as in ``master._Slave``)
    ``fmu``, ``fmi3``, ``m``, ``name``, the ctypes buffers ``real_in/bool_in/real_out/bool_out/
    real_prev/bool_prev/int_out``, value references ``vr_real_in/vr_bool_in/vr_real_out/vr_bool_out/
    vr_int_out``,
    ``rec_real/rec_bool`` (recorded inputs, in input order), ``n_rec_real/n_rec_bool``,
    ``conn_real/conn_bool`` (connections, in input order), ``out_index`` and ``feeds_connections``.
    """

    def __init__(self, library: ctypes.CDLL, slaves: Sequence[Any], scenario: Scenario, n_ticks: int,
                 columns: Sequence[tuple[Any, int]],
                 should_stop: Callable[[float], bool] | None = None) -> None:
        self._lib, self._scenario, self.slaves = library, scenario, list(slaves)
        self.n_ticks, self.tpo = n_ticks, scenario.ticks_per_output
        by_name = {s.name: s for s in self.slaves}
        delayed = {c.source.instance for c in scenario.connections if c.delay}
        stepping = getattr(scenario, "stepping", None)  # [stepping] (test doubles of a scenario may lack it)
        variable = set(stepping.variable) if stepping is not None else set()
        self._keep: list[Any] = []  # everything C points to
        self._instances = (_Instance * len(self.slaves))()
        rec = scenario.recorded
        channels: dict[str, np.ndarray] = {}  # each channel once, as float64 (booleans 0.0 / 1.0)

        def recorded(inputs: Sequence[Any]) -> int:
            table = (_Recorded * max(1, len(inputs)))()
            for item, i in zip(table, inputs):
                crossing = i.interpolation == "linear" and i.channel in rec.thresholds
                key = f"{i.channel} (column)" if crossing else i.channel
                if key not in channels:
                    source = rec.thresholds[i.channel][0] if crossing else rec.channels[i.channel]
                    channels[key] = np.ascontiguousarray(source, dtype=np.float64)
                item.values = channels[key].ctypes.data
                # a threshold channel: its column, sampled linearly, compared with the threshold (in factor)
                item.factor = rec.thresholds[i.channel][1] if crossing else i.factor
                item.linear = int(crossing or (i.interpolation == "linear"
                                               and rec.channels[i.channel].dtype != np.bool_))
            self._keep.append(table)
            return ctypes.addressof(table)

        for inst, s in zip(self._instances, self.slaves):
            fmu, prefix = s.fmu, "fmi3" if s.fmi3 else "fmi2"
            names = (("SetFloat64", "SetBoolean", "GetFloat64", "GetBoolean", "DoStep", "GetInt32") if s.fmi3 else
                     ("SetReal", "SetBoolean", "GetReal", "GetBoolean", "DoStep", "GetInteger"))
            fields = (("fmi3_set_float64", "fmi3_set_boolean", "fmi3_get_float64", "fmi3_get_boolean",
                       "fmi3_do_step", "fmi3_get_int32") if s.fmi3 else
                      ("fmi2_set_real", "fmi2_set_boolean", "fmi2_get_real", "fmi2_get_boolean", "fmi2_do_step",
                       "fmi2_get_integer"))
            for field, name in zip(fields, names):
                setattr(inst, field, ctypes.cast(getattr(fmu.dll, prefix + name), _vp).value)
            inst.component = fmu.component if isinstance(fmu.component, int) else fmu.component.value
            inst.fmi_version = 3 if s.fmi3 else 2
            inst.ticks_per_step = s.m
            for field in ("vr_real_in", "vr_bool_in", "real_in", "bool_in", "vr_real_out", "vr_bool_out",
                          "real_out", "real_prev", "bool_out", "bool_prev", "vr_int_out", "int_out"):
                setattr(inst, field, _address(getattr(s, field)))
            inst.n_real_in, inst.n_bool_in = len(s.real_in), len(s.bool_in)
            inst.n_rec_real, inst.n_rec_bool = s.n_rec_real, s.n_rec_bool
            inst.rec_real, inst.rec_bool = recorded(s.rec_real), recorded(s.rec_bool)
            inst.n_real_out, inst.n_bool_out, inst.n_int_out = len(s.real_out), len(s.bool_out), len(s.int_out)
            for field in ("real_in", "bool_in", "real_out", "bool_out", "int_out"):  # fewer for FMI 3 arrays
                setattr(inst, f"n_vr_{field}", len(getattr(s, f"vr_{field}")))
            inst.get_after_step = int(s.feeds_connections)
            inst.snapshot = int(s.name in delayed)
            inst.get_at_rows = int(bool(s.out_index))
            inst.variable = int(s.name in variable)
            for kind, conns, offset in (("real", s.conn_real, s.n_rec_real), ("bool", s.conn_bool, s.n_rec_bool)):
                links = (_Link * max(1, len(conns)))()
                for link, (pos, c) in zip(links, enumerate(conns, start=offset)):
                    src = by_name[c.source.instance]
                    _, j = src.out_index[c.source.variable]
                    buf = getattr(src, f"{kind}_prev" if c.delay else f"{kind}_out")
                    link.source, link.source_kind, link.position = _address(buf, j), _kind(buf), pos
                    link.factor = c.factor if kind == "real" else 1.0
                self._keep.append(links)
                setattr(inst, f"{kind}_links", ctypes.addressof(links))
                setattr(inst, f"n_{kind}_links", len(conns))
        self._columns = (_Column * max(1, len(columns)))()
        for col, (buf, j) in zip(self._columns, columns):
            col.source, col.kind = _address(buf, j), _kind(buf)
        self.width = 1 + len(columns)
        self._rows = np.empty((MAX_CHUNK_ROWS + 1, self.width))
        self.pending: BaseException | None = None  # raised by should_stop inside a chunk
        self._callback = None
        if should_stop is not None:
            self._callback = STOP_CALLBACK(functools.partial(self._ask, should_stop))
        self._plan = _Plan(start=scenario.start_time, base=scenario.base_step, n_ticks=n_ticks,
                           ticks_per_output=self.tpo, n_instances=len(self.slaves), n_columns=len(columns),
                           instances=self._instances, columns=self._columns)
        if self._callback is not None:  # else NULL: C never calls back
            self._plan.should_stop = self._callback
        self._plan.fine = 1
        if stepping is not None:
            gates = (_Gate * len(stepping.fine_when))()
            for gate, g in zip(gates, stepping.fine_when):
                kind, j = by_name[g.output.instance].out_index[g.output.variable]
                buf = getattr(by_name[g.output.instance], f"{kind}_out")
                gate.source, gate.kind = _address(buf, j), _kind(buf)
                gate.threshold, gate.sense = g.threshold, _SENSES[g.sense]
            self._keep.append(gates)
            self._plan.gates, self._plan.n_gates = gates, len(gates)
            self._plan.ticks_per_interval = stepping.ticks_per_interval
            self._plan.hold_intervals = stepping.hold_intervals
            self._plan.first_variable = next(i for i, s in enumerate(self.slaves) if s.name in variable)
        watched = getattr(scenario, "on_change", ())  # [[on_change]] (test doubles of a scenario may lack it)
        self._watches = (_Watch * max(1, len(watched)))()
        for watch, entry in zip(self._watches, watched):
            src = by_name[entry.output.instance]
            kind, j = src.out_index[entry.output.variable]
            buf = getattr(src, f"{kind}_out")
            watch.source, watch.kind, watch.boolean = _address(buf, j), _kind(buf), int(kind == "bool")
            watch.ticks_per_step, watch.equals = src.m, int(entry.equals)
            watch.last = int(buf[j] != 0) if kind == "bool" else int(buf[j])  # the master sets it too (remember)
        self._plan.watches, self._plan.n_watches = self._watches, len(watched)
        if rec is not None:
            time = np.ascontiguousarray(rec.time, dtype=np.float64)
            self._keep += [time, channels]
            self._plan.recorded_time, self._plan.recorded_samples = time.ctypes.data, len(time)
            self._plan.recorded_tolerance = 1e-9 * (rec.t_end - rec.t_start)  # as RecordedData.at
        self._outcome = _Outcome()
        self.stop_requested: Callable[[], bool] = lambda: False  # also checked by the callback

    def _ask(self, should_stop: Callable[[float], bool], t: float) -> int:
        try:
            return 1 if should_stop(t) or self.stop_requested() else 0
        except BaseException as exc:  # noqa: BLE001 - re-raised by run_chunk after the rows are saved
            self.pending = exc
            return 1

    def interval_counts(self) -> tuple[int, int, int]:
        """[stepping]: the intervals evaluated fine and coarse, and the doSteps of the variable instances."""
        plan = self._plan
        return plan.fine_intervals, plan.coarse_intervals, plan.variable_steps

    def remembered(self) -> list[int]:
        """[[on_change]]: each entry's output value at its previous check (C updates them as it steps)."""
        return [self._watches[i].last for i in range(self._plan.n_watches)]

    def remember(self, values: Sequence[int]) -> None:
        """[[on_change]]: set the values the entries compare with (after the master checked an event's tick)."""
        for i, value in enumerate(values):
            self._watches[i].last = int(value)

    def max_ticks(self) -> int:
        """The largest chunk the buffers allow."""
        return min(MAX_CHUNK_TICKS, MAX_CHUNK_ROWS * self.tpo)

    def run_chunk(self, first: int, last: int) -> Outcome:
        """Ticks [first, last) in C."""
        out = self._outcome
        self._lib.stp_run(ctypes.byref(self._plan), first, last, self._rows.ctypes.data, ctypes.byref(out))
        name, function = "", ""
        if out.code in (TERMINATED, FAILED, OUT_OF_RECORDING):
            s = self.slaves[out.instance]
            name = s.name
            if out.code == FAILED:
                function = ("fmi3" if s.fmi3 else "fmi2") + _FUNCTIONS[3 if s.fmi3 else 2][out.function]
        return Outcome(out.code, out.tick, self._rows[: out.rows], name, function, out.status, out.time)

    def raise_out_of_recording(self, outcome: Outcome) -> None:
        """Raise the RecordedDataError the Python path raises for ``outcome`` (code OUT_OF_RECORDING): that of
        ``RecordedData.at`` for the instance's first recorded input at the time C found outside the recording."""
        s = next(s for s in self.slaves if s.name == outcome.instance)
        first = (list(s.rec_real) + list(s.rec_bool))[0]
        self._scenario.recorded.at(first.channel, np.array([outcome.time]), first.interpolation)
        raise RuntimeError(f"the stepper found t = {outcome.time!r} s outside the recording of instance "
                           f"{outcome.instance!r}, but RecordedData.at accepts it")  # the two checks disagree
