"""Calibration spec files (TOML): what to fit, to which data, how.

Parsed by :func:`load_spec` into a frozen :class:`CalibrationSpec`; structure, types and the
relations that need no FMU (bounds reversed, initial value outside the bounds, empty or reversed
segments) are checked here, the names (parameters, outputs, channels) when the scenario is loaded
(:mod:`milling_twin.orchestrator.calibrate.scenario_fit`). Every problem is a :class:`CalibrationSpecError`
naming the spec file and the TOML key. Paths are relative to the spec file's folder.

Format (kind "scenario", the default: fit parameters of the FMU instances of a scenario to its
recorded data)::

    [calibration]
    name = "umich_power"              # letters, digits, "_", "-", "."; names <out>/calibration/<name>/
    description = "..."               # optional
    kind = "scenario"                 # or "slot_forces" (see below)
    scenario = "../umich_power.toml"  # the scenario: FMU instances, recorded data, inputs, connections
    parameter_set = "umich_power.params.toml"       # the calibrated values: written as <out>/calibration/
                                      # <name>/umich_power.params.toml; this file (the committed set) changes
                                      # only when the set is published to it (calibrate(..., write_set=...))
    calibrated_scenario = "umich_power_calibrated.toml"  # optional: the re-simulation runs this scenario
                                      # file, which must apply parameter_set by name (the set just written
                                      # is applied after it)

    [parameters."power.c1"]           # "instance.variable", a Float64 parameter of the instance
    initial = 0.264                   # optional: default the scenario's value, else the FMU's start
    min = 0.0                         # optional: default the FMU's min (it must lie inside it)
    max = 2.0                         # optional: default the FMU's max
    unit = "W.s/rad"                  # optional unit of initial/min/max/scale/start_range (default SI)
    scale = 0.3                       # optional typical size for the optimiser (default |initial|, or 1)
    start_range = [0.1, 1.0]          # optional: where multi-start draws its starts (default below)

    [[outputs]]                       # a model output against a recorded channel
    simulated = "power.P_total"       # "instance.variable", a Float64 output of the instance
    recorded = "spindle_power"        # a channel of the scenario's [recorded] data
    weight = 1.0                      # optional, > 0
    unit = "kW"                       # optional display unit of the report
    sigma = 0.02                      # optional noise standard deviation (display unit); see [solver].noise

    [segments]                        # recorded-time windows [start, end] in s
    learning = [[0.0, 70.0]]
    validation = [[70.0, 105.4]]      # optional (no validation figures without it)

    [alignment]                       # optional; default method "none" (recorded time = simulated time)
    method = "dtw"                    # "none" or a method of orchestrator.align ("multiscale", "dtw", "patent")
    simulated = ["power.spindle_speed", "mrr.feed_velocity_x", "mrr.feed_velocity_y"]
    recorded = ["spindle_speed", "feed_x", "feed_y"]   # three of each, same units pairwise
    output_delay = 0.0                # s, see orchestrator.align.trajectory
    min_confidence = 0.0              # pairs whose alignment confidence is lower are not used
    refuse_below = 0.3                # an alignment whose median confidence is lower has failed: refused with a
                                      # CalibrationError naming the recording, segment and confidence (default
                                      # DEFAULT_MIN_CONFIDENCE of orchestrator.align.segments, as `milling-twin
                                      # align temporal` uses it)

    [inputs."power.mrr"]              # optional, per input of the fitted equations (data or connection)
    floor = 1e-300                    # SI: the fit reads the input as max(value, floor) (see docs/calibration.md: a
                                      # derivative the models/ expression leaves undefined at 0)

    [solver]                          # all optional
    starts = 4                        # multi-start: the initial values, then starts - 1 drawn ones
    seed = 0
    max_iterations = 200
    tolerance = 1e-10                 # IPOPT tol; with Levenberg-Marquardt: relative decrease of the objective
                                      # at which the iterations stop
    hessian = "gauss-newton"          # or "exact"
    algorithm = "auto"                # "ipopt" (interior point), "levenberg-marquardt" (projected, bounds only:
                                      # no multiple shooting) or "auto": IPOPT, Levenberg-Marquardt on the FMU
                                      # path and for the slot-forces waveform
    shooting = "multiple"             # models with states: "multiple" or "single"
    shooting_interval = 100           # steps per shooting interval
    noise = "estimate"                # per-output noise level: "estimate" (two-stage: refit with each
                                      # output weighted by 1/its residual RMS) or "sigma" (given sigmas)
    derivatives = "auto"              # "exact": casadi derivatives of the models/ equations (an error where
                                      # they cannot express the outputs); "finite-differences": the FMUs
                                      # re-simulated for every evaluation, Jacobian by finite differences
                                      # (orchestrator/calibrate/fmu_outputs.py); "auto": exact where possible
    fd_method = "forward"             # finite differences: "forward" (p runs per Jacobian) or "central" (2p)
    fd_step = 1.5e-8                  # relative step (default sqrt(eps) forward, eps^(1/3) central)
    workers = 2                       # parallel fit through the FMUs (its simulations as tasks, the starts at
                                      # once; orchestrator/calibrate/parallel.py; the serial result bit for bit):
                                      # N local worker processes; 0 (default): serial, in this process
    scheduler = "tcp://host:8786"     # or a dask scheduler file (relative to this file): an existing cluster
                                      # instead of local workers (not both)

    [statistics]                      # all optional: flag thresholds
    condition = 100.0                 # near-singular direction: condition index above this
    correlation = 0.95                # |correlation| above this is flagged
    relative_se = 0.5                 # standard error above this fraction of |estimate|: poorly determined

Default start ranges: ``start_range`` if given; else the bounds when both are finite and at most
100 scales apart; else initial/4 .. initial*4 (log-uniform) for a positive initial value, and
initial -/+ 2 scales otherwise, clipped to the bounds.

Kind "runs" (one machine, several recordings: the fitted outputs of one FMU instance whose inputs come
from data; the scenario is the template every recording runs through, its ``[recorded].file`` replaced by
each run's file; ``[segments]`` and ``[alignment]`` do not apply: each run is paired on its recorded
clock, inside the consistent segments its ``[recorded.checks]`` finds)::

    [calibration]
    kind = "runs"
    scenario = "../umich_power.toml"
    ...
    [runs]
    folder = "../../../shared/data/umich_cnc"   # relative to this file; `--data DIR` replaces it
    files = ["experiment_01.csv", "experiment_02.csv"]   # the runs, named by their file stems, or a pattern:
                                      # files = "experiment_*.csv" (every match in the folder, sorted)
    per_run = ["power.P_standby"]     # optional: parameters fitted for every run on its own (nuisance), not
                                      # shared; each must also be in [parameters]
    cross_validation = true           # leave-one-run-out: each run predicted by the set fitted without it
    intervals = "bootstrap"           # 95 % intervals: "bootstrap" (moving blocks within segments, default) or
                                      # "hac" (Newey-West sandwich); orchestrator/calibrate/statistics.py
    block = 20                        # bootstrap: pairs per block (a 10 Hz recording: 2 s)
    replicates = 200                  # bootstrap replicates
    hac_lags = 6                      # optional: lags of the HAC covariance (default: the Newey-West rule)

Kind "slot_forces" (the cutting-force coefficients from the slot-milling recordings, read as
``milling_twin.orchestrator.validation.slot_milling`` reads them; ``[[outputs]]``, ``[segments]``,
``[alignment]`` and ``[inputs]`` do not apply)::

    [calibration]
    kind = "slot_forces"
    scenario = "../slot_milling.toml" # the CuttingForce instance "force" and its assumed geometry
    ...
    [slot_forces]
    learning_feeds = [300, 900, 1500] # mm/min, files of the data folder
    validation_feeds = [600, 1200]
    runout = true                     # also fit force.runout_offset and force.runout_angle
    revolutions = 0                   # whole revolutions used per recording (0: all)
    bootstrap = 200                   # intervals: replicates of the revolution bootstrap (0: i.i.d. intervals)
    leave_one_out = false             # also the leave-one-feed-out table over all feeds of the data folder
    compile = true                    # the force model and its derivatives as machine code (C compiler, cached;
                                      # orchestrator/calibrate/compiled.py), else casadi's virtual machine
    [parameters."force.Ktc"]          # the six coefficients (and runout ones): bounds, units, ...
"""
from __future__ import annotations

import hashlib
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NoReturn

from milling_twin.orchestrator.toml_access import TomlAccess
from milling_twin.orchestrator.safe_names import name_problem
from milling_twin.orchestrator.calibrate.errors import CalibrationSpecError
from milling_twin.orchestrator.calibrate.lsq import ALGORITHMS
from milling_twin.orchestrator.scenario import Ref

__all__ = ["AlignmentSpec", "CalibrationSpec", "OutputSpec", "ParameterSpec", "RunsSpec", "SlotForcesSpec",
           "SolverSpec", "StatisticsSpec", "load_spec"]

KINDS = ("scenario", "slot_forces", "runs")
ALIGNMENT_METHODS = ("none", "multiscale", "dtw", "patent")
DERIVATIVES = ("auto", "exact", "finite-differences")
_NAME_RE = re.compile(r"^[A-Za-z0-9_.-]+$")


@dataclass(frozen=True)
class ParameterSpec:
    """One parameter to fit, as written (values in ``unit``; None: take the default)."""

    ref: Ref  # instance.variable
    key: str  # the TOML key, for messages
    initial: float | None = None
    min: float | None = None
    max: float | None = None
    unit: str | None = None
    scale: float | None = None
    start_range: tuple[float, float] | None = None

    @property
    def name(self) -> str:
        return str(self.ref)

    @property
    def instance(self) -> str:
        return self.ref.instance

    @property
    def variable(self) -> str:
        return self.ref.variable


@dataclass(frozen=True)
class OutputSpec:
    simulated: Ref
    recorded: str
    key: str
    weight: float = 1.0
    unit: str | None = None
    sigma: float | None = None  # in ``unit`` (else the output's SI unit)


@dataclass(frozen=True)
class AlignmentSpec:
    method: str = "none"
    simulated: tuple[Ref, ...] = ()
    recorded: tuple[str, ...] = ()
    output_delay: float = 0.0
    min_confidence: float = 0.0
    refuse_below: float = 0.3  # = orchestrator.align.segments.DEFAULT_MIN_CONFIDENCE (importing align here
    # would load it whenever a spec is read; tests/test_calibrate_spec.py checks the two agree)


@dataclass(frozen=True)
class SolverSpec:
    starts: int = 4
    seed: int = 0
    max_iterations: int = 200
    tolerance: float = 1e-10
    hessian: str = "gauss-newton"
    algorithm: str = "auto"  # "auto" (the model's own), "ipopt" or "levenberg-marquardt"
    shooting: str = "multiple"
    shooting_interval: int = 100
    noise: str = "estimate"
    derivatives: str = "auto"
    fd_method: str = "forward"
    fd_step: float | None = None  # None: the method's default
    workers: int = 0  # parallel fit: local worker processes (0: serial, in this process)
    scheduler: str | None = None  # parallel fit on an existing cluster: address or scheduler file


@dataclass(frozen=True)
class StatisticsSpec:
    condition: float = 100.0
    correlation: float = 0.95
    relative_se: float = 0.5


@dataclass(frozen=True)
class SlotForcesSpec:
    learning_feeds: tuple[float, ...]
    validation_feeds: tuple[float, ...]
    runout: bool = True
    revolutions: int = 0
    bootstrap: int = 200  # replicates of the revolution bootstrap of the intervals (0: the i.i.d. intervals)
    leave_one_out: bool = False  # also fit every feed's complement and predict it (the leave-one-feed-out table)
    compile: bool = True  # the force model compiled to machine code (compiled.py), the same numbers, faster


@dataclass(frozen=True)
class RunsSpec:
    folder: Path
    files: tuple[str, ...]  # file names, or one glob pattern (see ``pattern``)
    per_run: tuple[Ref, ...] = ()
    cross_validation: bool = True
    hac_lags: int | None = None  # None: newey_west_lags(pairs)
    intervals: str = "bootstrap"  # or "hac"
    block: int = 20
    replicates: int = 200

    @property
    def pattern(self) -> str | None:
        """The glob pattern the runs are found by, if ``files`` is one."""
        return self.files[0] if len(self.files) == 1 and any(c in self.files[0] for c in "*?[") else None


@dataclass(frozen=True)
class CalibrationSpec:
    path: Path
    sha256: str
    name: str
    description: str
    kind: str
    scenario: Path
    parameter_set: Path
    calibrated_scenario: Path | None
    parameters: tuple[ParameterSpec, ...]
    outputs: tuple[OutputSpec, ...] = ()
    learning: tuple[tuple[float, float], ...] = ()
    validation: tuple[tuple[float, float], ...] = ()
    alignment: AlignmentSpec = field(default_factory=AlignmentSpec)
    input_floors: dict[Ref, float] = field(default_factory=dict)
    solver: SolverSpec = field(default_factory=SolverSpec)
    statistics: StatisticsSpec = field(default_factory=StatisticsSpec)
    slot_forces: SlotForcesSpec | None = None
    runs: RunsSpec | None = None

    def fail(self, key: str, message: str) -> NoReturn:
        raise CalibrationSpecError(self.path, key, message)


class _Ctx(TomlAccess):
    """Typed access to this file's TOML values; errors are CalibrationSpecErrors naming file and key."""

    error = CalibrationSpecError


def _segments(ctx: _Ctx, table: dict, name: str, required: bool) -> tuple[tuple[float, float], ...]:
    key = f"[segments].{name}"
    if name not in table:
        if required:
            ctx.fail(key, "missing required key: a list of [start, end] windows in s")
        return ()
    raw = table[name]
    if not isinstance(raw, list) or not raw:
        ctx.fail(key, f"expected a non-empty list of [start, end] windows, got {raw!r}")
    out = []
    for i, item in enumerate(raw):
        if (not isinstance(item, list) or len(item) != 2
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in item)):
            ctx.fail(f"{key}[{i}]", f"expected [start, end] in s, got {item!r}")
        if item[1] <= item[0]:
            ctx.fail(f"{key}[{i}]", f"end {item[1]!r} must be after start {item[0]!r}")
        out.append((float(item[0]), float(item[1])))
    return tuple(out)


def _parameter(ctx: _Ctx, name: str, raw: Any) -> ParameterSpec:
    key = f'[parameters."{name}"]'
    ref = Ref.parse(name, key, ctx.fail)
    table = ctx.table(raw, key, ("initial", "min", "max", "unit", "scale", "start_range"))
    lo, hi = ctx.number(table, key, "min", None), ctx.number(table, key, "max", None)
    if lo is not None and hi is not None and lo >= hi:
        ctx.fail(f"{key}.max", f"bounds reversed or empty: min {lo!r} >= max {hi!r}")
    initial = ctx.number(table, key, "initial", None)
    if initial is not None and ((lo is not None and initial < lo) or (hi is not None and initial > hi)):
        ctx.fail(f"{key}.initial", f"{initial!r} lies outside [min, max] = [{lo!r}, {hi!r}]")
    start_range = None
    if "start_range" in table:
        sr = table["start_range"]
        if (not isinstance(sr, list) or len(sr) != 2
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in sr)
                or sr[1] <= sr[0]):
            ctx.fail(f"{key}.start_range", f"expected [low, high] with low < high, got {sr!r}")
        start_range = (float(sr[0]), float(sr[1]))
    return ParameterSpec(ref=ref, key=key, initial=initial, min=lo, max=hi, unit=ctx.string(table, key, "unit", None),
                         scale=ctx.number(table, key, "scale", None, positive=True), start_range=start_range)


def _outputs(ctx: _Ctx, doc: dict) -> tuple[OutputSpec, ...]:
    items = doc.get("outputs")
    if not isinstance(items, list) or not items:
        ctx.fail("[[outputs]]", "define at least one [[outputs]] table (simulated output vs recorded channel)")
    out = []
    for i, item in enumerate(items):
        key = f"[[outputs]][{i}]"
        table = ctx.table(item, key, ("simulated", "recorded", "weight", "unit", "sigma"))
        out.append(OutputSpec(simulated=Ref.parse(table.get("simulated"), f"{key}.simulated", ctx.fail),
                              recorded=ctx.string(table, key, "recorded"), key=key,
                              weight=ctx.number(table, key, "weight", 1.0, positive=True),
                              unit=ctx.string(table, key, "unit", None),
                              sigma=ctx.number(table, key, "sigma", None, positive=True)))
    seen = [(o.simulated, o.recorded) for o in out]
    for i, s in enumerate(seen):
        if s in seen[:i]:
            ctx.fail(f"[[outputs]][{i}]", f"the pair {out[i].simulated} / {out[i].recorded} is listed twice")
    return tuple(out)


def _alignment(ctx: _Ctx, raw: Any) -> AlignmentSpec:
    key = "[alignment]"
    table = ctx.table(raw, key, ("method", "simulated", "recorded", "output_delay", "min_confidence",
                                 "refuse_below"))
    method = ctx.string(table, key, "method", "none", ALIGNMENT_METHODS)
    delay = ctx.number(table, key, "output_delay", 0.0, minimum=0.0)
    confidence = ctx.number(table, key, "min_confidence", AlignmentSpec.min_confidence, minimum=0.0)
    if confidence > 1:
        ctx.fail(f"{key}.min_confidence", f"must lie in [0, 1], got {confidence!r}")
    refuse = ctx.number(table, key, "refuse_below", AlignmentSpec.refuse_below, minimum=0.0)
    if refuse > 1:
        ctx.fail(f"{key}.refuse_below", f"must lie in [0, 1], got {refuse!r}")
    if method == "none":
        for name in ("simulated", "recorded"):
            if name in table:
                ctx.fail(f"{key}.{name}", "not used with method = \"none\"")
        return AlignmentSpec("none", (), (), delay, confidence, refuse)
    simulated = tuple(Ref.parse(s, f"{key}.simulated[{i}]", ctx.fail)
                      for i, s in enumerate(ctx.strings(table, key, "simulated", 3)))
    return AlignmentSpec(method, simulated, ctx.strings(table, key, "recorded", 3), delay, confidence, refuse)


def _solver(ctx: _Ctx, raw: Any, base: Path) -> SolverSpec:
    key = "[solver]"
    table = ctx.table(raw, key, ("starts", "seed", "max_iterations", "tolerance", "hessian", "algorithm", "shooting",
                                 "shooting_interval", "noise", "derivatives", "fd_method", "fd_step", "workers",
                                 "scheduler"))
    step = ctx.number(table, key, "fd_step", None, positive=True)
    if step is not None and step >= 0.1:
        ctx.fail(f"{key}.fd_step", f"{step!r}: a relative step, far below 1 (default 1.5e-8 forward, 6.1e-6 central)")
    workers = ctx.integer(table, key, "workers", 0, 0)
    scheduler = ctx.string(table, key, "scheduler", None)
    if scheduler is not None:
        if not scheduler.strip():
            ctx.fail(f"{key}.scheduler", "expected an address (tcp://host:8786) or a scheduler file, got \"\"")
        if workers:
            ctx.fail(f"{key}.workers", f"workers = {workers} and scheduler = {scheduler!r}: give one (the cluster's "
                                       "workers are the scheduler's)")
        if "://" not in scheduler:
            scheduler = str(base / scheduler)
    return SolverSpec(starts=ctx.integer(table, key, "starts", 4, 1), seed=ctx.integer(table, key, "seed", 0, 0),
                      max_iterations=ctx.integer(table, key, "max_iterations", 200, 1),
                      tolerance=ctx.number(table, key, "tolerance", 1e-10, positive=True),
                      hessian=ctx.string(table, key, "hessian", "gauss-newton", ("gauss-newton", "exact")),
                      algorithm=ctx.string(table, key, "algorithm", "auto", ("auto", *ALGORITHMS)),
                      shooting=ctx.string(table, key, "shooting", "multiple", ("multiple", "single")),
                      shooting_interval=ctx.integer(table, key, "shooting_interval", 100, 1),
                      noise=ctx.string(table, key, "noise", "estimate", ("estimate", "sigma")),
                      derivatives=ctx.string(table, key, "derivatives", "auto", DERIVATIVES),
                      fd_method=ctx.string(table, key, "fd_method", "forward", ("forward", "central")),
                      fd_step=step, workers=workers, scheduler=scheduler)


def _statistics(ctx: _Ctx, raw: Any) -> StatisticsSpec:
    key = "[statistics]"
    table = ctx.table(raw, key, ("condition", "correlation", "relative_se"))
    correlation = ctx.number(table, key, "correlation", 0.95, positive=True)
    if correlation >= 1:
        ctx.fail(f"{key}.correlation", f"must lie in (0, 1), got {correlation!r}")
    return StatisticsSpec(condition=ctx.number(table, key, "condition", 100.0, positive=True), correlation=correlation,
                          relative_se=ctx.number(table, key, "relative_se", 0.5, positive=True))


def _feeds(ctx: _Ctx, table: dict, name: str) -> tuple[float, ...]:
    key = f"[slot_forces].{name}"
    raw = table.get(name)
    if (not isinstance(raw, list) or not raw
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0 for v in raw)):
        ctx.fail(key, f"expected a non-empty list of feeds in mm/min, got {raw!r}")
    if len(set(raw)) != len(raw):
        ctx.fail(key, f"a feed is listed twice: {raw!r}")
    return tuple(float(v) for v in raw)


def _slot_forces(ctx: _Ctx, raw: Any) -> SlotForcesSpec:
    key = "[slot_forces]"
    table = ctx.table(raw, key, ("learning_feeds", "validation_feeds", "runout", "revolutions", "bootstrap",
                                 "leave_one_out", "compile"))
    learning, validation = _feeds(ctx, table, "learning_feeds"), _feeds(ctx, table, "validation_feeds")
    if len(learning) < 2:
        ctx.fail(f"{key}.learning_feeds", "give at least two feeds (a line per axis needs two)")
    both = sorted(set(learning) & set(validation))
    if both:
        ctx.fail(f"{key}.validation_feeds", f"feed(s) {both} are also learning feeds: validation data must be unseen")
    runout = table.get("runout", True)
    if not isinstance(runout, bool):
        ctx.fail(f"{key}.runout", f"expected true or false, got {runout!r}")
    switches = {}
    for name, default in (("leave_one_out", False), ("compile", True)):
        switches[name] = table.get(name, default)
        if not isinstance(switches[name], bool):
            ctx.fail(f"{key}.{name}", f"expected true or false, got {switches[name]!r}")
    return SlotForcesSpec(learning, validation, runout, ctx.integer(table, key, "revolutions", 0, 0),
                          ctx.integer(table, key, "bootstrap", 200, 0), **switches)


def _runs(ctx: _Ctx, raw: Any, base: Path, parameters: tuple[ParameterSpec, ...]) -> RunsSpec:
    key = "[runs]"
    table = ctx.table(raw, key, ("folder", "files", "per_run", "cross_validation", "hac_lags", "intervals", "block",
                                 "replicates"))
    files = table.get("files")
    if isinstance(files, str) and files and any(c in files for c in "*?["):
        files = [files]  # a pattern
    elif not isinstance(files, list) or not files or not all(isinstance(f, str) and f for f in files):
        ctx.fail(f"{key}.files", f"expected a non-empty list of recording file names or a pattern such as "
                                 f"\"experiment_*.csv\", got {files!r}")
    stems = [Path(f).stem for f in files]
    twice = sorted({s for s in stems if stems.count(s) > 1})
    if twice:
        ctx.fail(f"{key}.files", f"run name(s) {twice} appear twice (a run is named by its file's stem)")
    fitted = {p.ref for p in parameters}
    per_run = []
    raw_per_run = table.get("per_run", [])
    if not isinstance(raw_per_run, list):
        ctx.fail(f"{key}.per_run", f"expected a list of \"instance.variable\" names, got {raw_per_run!r}")
    for i, name in enumerate(raw_per_run):
        ref = Ref.parse(name, f"{key}.per_run[{i}]", ctx.fail)
        if ref not in fitted:
            ctx.fail(f"{key}.per_run[{i}]", f"{ref} is not in [parameters]: a per-run parameter is a fitted one")
        per_run.append(ref)
    if len(per_run) == len(fitted):
        ctx.fail(f"{key}.per_run", "every fitted parameter is per run: nothing would be shared between the runs")
    cross = table.get("cross_validation", True)
    if not isinstance(cross, bool):
        ctx.fail(f"{key}.cross_validation", f"expected true or false, got {cross!r}")
    lags = table.get("hac_lags")
    if lags is not None:
        lags = ctx.integer(table, key, "hac_lags", 0, 0)
    return RunsSpec(base / ctx.string(table, key, "folder", "."), tuple(files), tuple(per_run), cross, lags,
                    ctx.string(table, key, "intervals", "bootstrap", ("bootstrap", "hac")),
                    ctx.integer(table, key, "block", 20, 1), ctx.integer(table, key, "replicates", 200, 20))


def load_spec(path: str | Path) -> CalibrationSpec:
    """Parse and check a calibration spec file (see the module text)."""
    path = Path(path)
    ctx = _Ctx(path)
    raw, doc = ctx.document("calibration")
    ctx.table(doc, "", ("calibration", "parameters", "outputs", "segments", "alignment", "inputs", "solver",
                        "statistics", "slot_forces", "runs"))
    key = "[calibration]"
    head = ctx.table(doc.get("calibration"), key, ("name", "description", "kind", "scenario", "parameter_set",
                                                   "calibrated_scenario"))
    name = ctx.string(head, key, "name")
    if not _NAME_RE.match(name):
        ctx.fail(f"{key}.name", f"{name!r}: use only letters, digits, '_', '-' and '.'")
    if name_problem(name) is not None:
        ctx.fail(f"{key}.name", f"{name!r} {name_problem(name)}: it names the folder <out>/calibration/<name>/")
    kind = ctx.string(head, key, "kind", "scenario", KINDS)
    base = path.parent
    scenario = base / ctx.string(head, key, "scenario")
    if not scenario.is_file():
        ctx.fail(f"{key}.scenario", f"scenario file {scenario} not found")
    parameter_set = base / ctx.string(head, key, "parameter_set")
    if name_problem(parameter_set.name) is not None:  # its file name is written under <out>/calibration/<name>/
        ctx.fail(f"{key}.parameter_set", f"file name {parameter_set.name!r} {name_problem(parameter_set.name)}")
    if parameter_set.suffix != ".toml":
        ctx.fail(f"{key}.parameter_set", f"{parameter_set.name}: the parameter set is a .toml file")
    calibrated = ctx.string(head, key, "calibrated_scenario", None)
    calibrated_path = base / calibrated if calibrated is not None else None
    if calibrated_path is not None and not calibrated_path.is_file():
        ctx.fail(f"{key}.calibrated_scenario", f"scenario file {calibrated_path} not found")

    params = ctx.table(doc.get("parameters"), "[parameters]", list(doc.get("parameters") or {}))
    if not params:
        ctx.fail("[parameters]", "name at least one parameter to fit as [parameters.\"instance.variable\"]")
    parameters = tuple(_parameter(ctx, n, v) for n, v in params.items())

    common = dict(path=path, sha256=hashlib.sha256(raw).hexdigest(), name=name,
                  description=ctx.string(head, key, "description", ""), kind=kind, scenario=scenario,
                  parameter_set=parameter_set, calibrated_scenario=calibrated_path, parameters=parameters,
                  solver=_solver(ctx, doc.get("solver", {}), base),
                  statistics=_statistics(ctx, doc.get("statistics", {})))
    if kind == "slot_forces":
        for section in ("outputs", "segments", "alignment", "inputs"):
            if section in doc:
                ctx.fail(f"[{section}]", "not used by kind = \"slot_forces\" (its data and outputs are fixed)")
        if "slot_forces" not in doc:
            ctx.fail("[slot_forces]", "missing required table for kind = \"slot_forces\"")
        return CalibrationSpec(**common, slot_forces=_slot_forces(ctx, doc["slot_forces"]))

    if "slot_forces" in doc:
        ctx.fail("[slot_forces]", "only used by kind = \"slot_forces\"")
    if kind == "runs":
        for section in ("segments", "alignment"):
            if section in doc:
                ctx.fail(f"[{section}]", "not used by kind = \"runs\" (each run is paired on its recorded clock, "
                                         "inside the consistent segments of its [recorded.checks])")
        if "runs" not in doc:
            ctx.fail("[runs]", "missing required table for kind = \"runs\"")
        return CalibrationSpec(**common, outputs=_outputs(ctx, doc), input_floors=_floors(ctx, doc),
                               runs=_runs(ctx, doc["runs"], base, parameters))
    if "runs" in doc:
        ctx.fail("[runs]", "only used by kind = \"runs\"")
    segments = ctx.table(doc.get("segments"), "[segments]", ("learning", "validation"))
    learning, validation = _segments(ctx, segments, "learning", True), _segments(ctx, segments, "validation", False)
    for i, (a, b) in enumerate(validation):
        for c, d in learning:
            if a < d and c < b:
                ctx.fail(f"[segments].validation[{i}]", f"[{a!r}, {b!r}] overlaps the learning window [{c!r}, {d!r}]: "
                                                        "validation data must be unseen")
    return CalibrationSpec(**common, outputs=_outputs(ctx, doc), learning=learning, validation=validation,
                           alignment=_alignment(ctx, doc.get("alignment", {})), input_floors=_floors(ctx, doc))


def _floors(ctx: _Ctx, doc: dict) -> dict[Ref, float]:
    floors: dict[Ref, float] = {}
    inputs = ctx.table(doc.get("inputs", {}), "[inputs]", list(doc.get("inputs") or {}))
    for name, item in inputs.items():
        k = f'[inputs."{name}"]'
        floors[Ref.parse(name, k, ctx.fail)] = ctx.number(ctx.table(item, k, ("floor",)), k, "floor")
    return floors
