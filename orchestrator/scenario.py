"""Scenario files: which FMUs to co-simulate, how they are fed and what is recorded.

A scenario is a TOML file, parsed by :func:`load_scenario` into frozen dataclasses
and validated against the FMUs' model descriptions and the recorded data. Every
problem is a :class:`ScenarioError` whose message starts with the scenario file and
the TOML key, e.g. ``scenarios/x.toml: [fmus.power].parameters.c9: unknown ...``.

Format (all times in seconds; paths are relative to the scenario file's folder)::

    [scenario]
    name = "umich_power"        # letters, digits, "_", "-", "."; names the run folder
    description = "..."         # optional
    start_time = 0.0            # optional, default 0
    stop_time = 100.0           # optional if [recorded] is given: default its last time
    output_interval = 0.1       # outputs are recorded on this grid
    parameter_sets = ["calibration/umich_power.params.toml"]   # optional, see below

    [fmus.power]                # instance "power"; instances are listed in file order
    fmu = "SpindlePower"        # <fmu_dir>/SpindlePower.fmu (fmi = 3) or
                                # <fmu_dir>/SpindlePower_fmi2.fmu (fmi = 2);
                                # a value ending in ".fmu" is a path instead
    fmi = 3                     # 2 or 3, default 3
    step_size = 0.01
    [fmus.power.parameters]     # causality "parameter" only
    P_standby = 0.0                       # plain number: the variable's own (SI) unit
    P_idle = { value = 0.1, unit = "kW" } # converted by models.units
    [fmus.power.inputs]         # optional: constant values of inputs that nothing else feeds
    spindle_speed = { value = 6000, unit = "rpm" }   # (set with the parameters, before initialization)

    [recorded]                  # optional
    file = "data/experiment_01.csv"
    sample_period = 0.1         # or: time_column = "t", time_unit = "s"
    [recorded.channels]         # unit: of the file's values (default "1"); above/match
    spindle_speed = { column = "S1_ActualVelocity", unit = "rev/s" }   # make booleans,
    cutting = { column = "Machining_Process", match = "^Layer" }       # see recorded.py
    spindle_on = { column = "S1_ActualVelocity", unit = "rev/s", above = 1.0 }
    [recorded.checks]           # optional: physical checks and repair policy, see recording_checks_spec.py
    positions = ["x", "y", "z"]
    max_axis_speed = { value = 50.0, unit = "mm/s" }
    policy = "segment"

    [[inputs]]                  # recorded channel -> FMU input
    from = "spindle_speed"
    to = "power.spindle_speed"
    interpolation = "linear"    # or "hold"; boolean channels hold, threshold (above) channels switch
                                # where the interpolated column crosses (hold: at the sample)

    [[connections]]             # FMU output -> FMU input
    from = "mrr.mrr"
    to = "power.mrr"
    delay = false               # true: value of the previous communication point

    [[connections]]             # a whole array -> an array input of the same shape, element by element
    from = "workpiece.engagement"   # FMI 3: one array variable; FMI 2: the scalars engagement[i,j]
    to = "force.engagement"

    [outputs]
    record = ["power.P_total"]  # default: every output of every instance (Real, Boolean, Int32)

    [[compare]]                 # optional, for the report
    simulated = "power.P_total"
    recorded = "spindle_power"
    unit = "kW"                 # optional display unit of the plot

    [alignment]                 # optional: the [[compare]] pairs on the recording's own samples, each mapped to
    recorded = ["x", "y", "z"]  # the simulated moment of the same machining state by aligning these recorded
    simulated = ["interp.x", "interp.y", "interp.z"]   # positions with these simulated ones (orchestrator/align;
    method = "multiscale"       # default multiscale)

    [stepping]                  # optional: the engagement-driven variable communication step
    coarse_step = 1e-3          # s; the length of a coarse interval
    variable = ["force", "vibration"]      # instances that make one step per interval while no condition holds
    fine_when = [               # any one true -> the interval is fine (the variable instances take their own steps)
      { output = "workpiece.axial_depth", above = 0.0 },                        # Real: above / below a threshold
      { output = "workpiece.clearance", below = { value = 2.0, unit = "mm" } }, # (its unit, or { value, unit })
    ]                           # Boolean: { output = "...", is = true }
    hold = { value = 30, unit = "ms" }  # optional: intervals stay fine this long after a condition last held
                                        # (rounded up to whole coarse intervals; default and least: one)

    [[on_change]]               # optional, repeatable: set tunable parameters when an output changes
    output = "interp.tool_number"   # an Int32 or Boolean output (of an instance that is not variable)
    equals = 2                      # fires when the output changes to this value (Boolean: true/false)
    set = { "force.n_flutes" = 2, "force.tool_diameter" = { value = 6.0, unit = "mm" } }  # in this order

Parameter sets (``[scenario].parameter_sets``, and ``load_scenario(..., parameter_sets=...)``
after those) are TOML files of parameter values by instance, applied in order after the
instances' own ``parameters`` (a later value wins); ``orchestrator calibrate`` writes them::

    description = "..."         # optional
    [source]                    # optional, free-form provenance
    [parameters.power]          # instance "power" of the scenario
    c1 = 0.2531                 # checked like [fmus.power.parameters]: number (SI) or
    P_idle = { value = 0.09, unit = "kW" }   # { value, unit }, causality, type, range

An error in a set names the scenario key, the set file and its key, e.g.
``x.toml: [scenario].parameter_sets[0]: p.toml: [parameters.power].c9: unknown variable ...``.

Rules checked here: every reference names an existing instance, variable or channel
(candidates are listed otherwise); parameters are ``parameter`` variables and lie within
the FMU's min/max (Integer/Int32 ones take TOML integers); an instance's constant
``inputs`` are ``input`` variables within min/max that nothing else feeds; inputs and
connections target ``input`` variables of type Real/Float64 or Boolean, each input at
most once; units of connected variables (and of a channel and the input it feeds)
have the same dimension, and the factor between them is applied by the master;
booleans connect only to booleans. Arrays (Float64 with fixed dimensions in FMI 3; in FMI 2 the complete
groups of scalars ``name[i,j]``) are named whole in connections and ``record`` (they stand for their
elements, 1-based ``name[i,j]`` in row-major order, which may also be named one by one); an FMI 3 array input
is set whole, so it is fed by one connection from an array of the same shape, never element by element, by
a recorded channel or as a constant. Step sizes are positive; the base step is their greatest common divisor
(computed on the decimal values, to 1e-9 s) and must be at least 1/10000 of the
largest step; ``output_interval`` must be a multiple of it. Connections with
``delay = false`` must not form a cycle between instances (an algebraic loop; the
check is per instance, not per variable dependency). The execution order is the
topological order of instances along those connections, ties broken by file order.

``[alignment]``: 2 or 3 recorded channels and as many simulated outputs (Real, length units), in the same axis
order; a ``method`` of ``orchestrator.align.METHODS``. Without it a ``[[compare]]`` pair is compared at equal times.

``[stepping]`` (the master's loop in ``orchestrator/master.py`` states what it does): ``coarse_step`` is an integer
multiple of the base step and of the step of every ``variable`` instance (listed once each, at least one; their
FMUs declare canHandleVariableCommunicationStepSize="true"); it need not relate to ``output_interval`` (rows inside
a coarse interval hold the outputs of the step covering them). ``fine_when`` lists at least one condition, each
on a Real/Float64 output (``above`` or ``below``, strict, a number in the output's unit or ``{ value, unit }`` of
the same dimension) or a Boolean output (``is = true`` or ``false``) of an instance that steps at exactly
``coarse_step`` and precedes every variable instance in the execution order (so the condition reads the value at
the coarse interval's end). ``hold`` (s, or ``{ value, unit }``; default ``coarse_step``) is at least
``coarse_step``; it is rounded up to whole coarse intervals.

``[[on_change]]`` (when it fires: ``orchestrator/master.py``): ``output`` an Int32 or Boolean output of an
instance that is not a ``[stepping]`` variable instance (it must keep its own step grid); ``equals`` a whole
number (Int32) or true/false (Boolean); ``set`` at least one ``"instance.variable" = value``, each a parameter
with variability ``tunable`` (a ``fixed`` one is refused), its value checked and converted as in
``[fmus.<instance>.parameters]`` (units, types, range). :func:`on_change_toml` writes entries back as TOML.
"""
from __future__ import annotations

import copy
import math
import re
import zipfile
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from fractions import Fraction
from pathlib import Path
from typing import Any, NoReturn

import fmpy
import tomli_w
from fmpy import read_model_description

from milling_twin.orchestrator.toml_access import FileKeyError, TomlAccess
from milling_twin.orchestrator.safe_names import name_problem
from milling_twin.orchestrator.part.model import Part
from milling_twin.orchestrator.gcode.recognise import FILE_PARAMETERS, NotThatFileError
from milling_twin.orchestrator.recorded import ChannelSpec, RecordedData, RecordedDataError, load_recorded
from milling_twin.orchestrator.recording_checks_spec import check_table
from milling_twin.models.units import UnitError, conversion_factor

__all__ = [
    "Compare", "Connection", "FineWhen", "FmuInstance", "OnChange", "Ref", "RecordedInput", "Scenario",
    "ScenarioError", "Stepping", "Variable", "load_scenario", "on_change_toml", "with_values",
]

BUILD_HINT = ("build the FMUs first: `make build` (or `cmake -S . -B build && cmake --build build`), "
              "or pass --fmu-dir / set MILLING_TWIN_FMU_DIR")  # an FMU is missing from the FMU folder
MAX_STEP_RATIO = 10_000  # largest step / base step; beyond it steps are incommensurate
RECORDABLE_TYPES = ("real", "bool", "int")  # [outputs].record: Int32 outputs too (stored as int32)
_SUPPORTED_TYPES = {"Real": "real", "Float64": "real", "Boolean": "bool", "Integer": "int", "Int32": "int",
                    "String": "string"}
_NAME_RE = re.compile(r"^[A-Za-z0-9_.-]+$")


class ScenarioError(FileKeyError):
    """An invalid scenario; the message names the scenario file and the TOML key."""


@dataclass(frozen=True)
class Variable:
    """An FMU variable as far as the orchestrator cares. ``type``: "real", "bool" or
    the FMI type name when unsupported; ``unit``: "" when undeclared, "bool" for booleans;
    ``display_unit``: the model description's displayUnit ("" when it gives none)."""

    name: str
    value_reference: int
    type: str
    causality: str
    variability: str
    unit: str
    min: float | None = None
    max: float | None = None
    # A whole array (type "real[]"; FMI 3: one variable, FMI 2: a group of scalars "name[i,j]"): its shape and
    # the names of its elements, row-major. In FMI 3 each element is also a Variable of type "real" with the
    # array's value reference, ``array`` its array's name and ``element`` its position.
    shape: tuple[int, ...] = ()
    elements: tuple[str, ...] = ()
    array: str = ""
    element: int = 0
    display_unit: str = ""


@dataclass(frozen=True)
class Ref:
    """``instance.variable``: parsed once, where the text enters (a scenario, a spec, an API call), with
    :meth:`parse`; ``str(ref)`` gives the text back (the column name of the results)."""

    instance: str
    variable: str

    def __str__(self) -> str:
        return f"{self.instance}.{self.variable}"

    @classmethod
    def parse(cls, text: Any, where: str = "", fail: Callable[[str, str], NoReturn] | None = None) -> Ref:
        """``"instance.variable"`` (split at the first "."; both parts non-empty) as a Ref. ``where`` names
        the text in the message (a TOML key, ``with_values['x']``); ``fail(where, message)`` raises the
        caller's error, e.g. a TOML reader's ``fail`` (ScenarioError, CalibrationSpecError naming the file);
        without it a ValueError ``"<where>: expected "instance.variable", got ..."`` is raised."""
        if isinstance(text, cls):
            return text
        instance, _, variable = text.partition(".") if isinstance(text, str) else ("", "", "")
        if not instance or not variable:
            message = f"expected \"instance.variable\", got {text!r}"
            if fail is not None:
                fail(where, message)
            raise ValueError(f"{where}: {message}" if where else message)
        return cls(instance, variable)


@dataclass(frozen=True)
class FmuInstance:
    name: str
    path: Path
    fmi_version: int
    step_size: float
    ticks_per_step: int  # step_size / base step
    model_identifier: str
    instantiation_token: str
    parameters: Mapping[str, float | bool | int]  # SI values, by variable name
    variables: Mapping[str, Variable] = field(repr=False, compare=False)
    inputs: Mapping[str, float | bool | int] = field(default_factory=dict)  # constant inputs, SI


@dataclass(frozen=True)
class RecordedInput:
    channel: str
    target: Ref
    interpolation: str
    factor: float  # SI channel value * factor = value in the input's unit


@dataclass(frozen=True)
class Connection:
    source: Ref
    target: Ref
    delay: bool
    factor: float  # source value * factor = value in the target's unit


@dataclass(frozen=True)
class Compare:
    simulated: Ref
    recorded: str
    display_unit: str | None


@dataclass(frozen=True)
class Alignment:
    """``[alignment]``: compare on the recorded samples mapped to simulated time by aligning ``recorded`` position
    channels with ``simulated`` outputs (``method`` of orchestrator.align.METHODS)."""
    recorded: tuple[str, ...]
    simulated: tuple[Ref, ...]
    method: str = "multiscale"


@dataclass(frozen=True)
class FineWhen:
    """A condition of ``[stepping].fine_when``: ``output`` (Real) ``above``/``below`` ``threshold`` (strictly, in
    the output's unit), or (Boolean) ``is`` the truth of ``threshold`` (1.0 true, 0.0 false)."""

    output: Ref
    sense: str  # "above", "below" or "is"
    threshold: float

    def holds(self, value: float | bool | int) -> bool:
        """Whether the output's ``value`` (as read from its buffer: a float, an int or a bool) meets it."""
        if self.sense == "above":
            return value > self.threshold
        if self.sense == "below":
            return value < self.threshold
        return (value != 0) == (self.threshold != 0.0)


@dataclass(frozen=True)
class Stepping:
    """``[stepping]``: coarse intervals of ``ticks_per_interval`` base steps (``coarse_step``), in which the
    ``variable`` instances (execution order) make one step unless a ``fine_when`` condition holds now or held at
    one of the ``hold_intervals`` evaluations before (1: the previous one, so the interval the tool leaves
    material in is fine)."""

    coarse_step: float
    ticks_per_interval: int
    variable: tuple[str, ...]
    fine_when: tuple[FineWhen, ...]
    hold_intervals: int = 1


@dataclass(frozen=True)
class OnChange:
    """An ``[[on_change]]`` entry: when ``output`` (Int32 or Boolean) has changed at a communication point of its
    instance and now equals ``equals``, the master sets ``values`` (tunable parameters, SI values as
    ``[fmus.<instance>.parameters]`` gives them, in the order written) before any instance steps from there."""

    output: Ref
    equals: int | bool  # bool for a Boolean output
    values: tuple[tuple[Ref, float | bool | int | str], ...]

    def table(self) -> dict[str, Any]:
        """The entry as the TOML table it reads back from (values in SI units)."""
        return {"output": str(self.output), "equals": self.equals, "set": {str(r): v for r, v in self.values}}


def on_change_toml(tables: Sequence[Mapping[str, Any]]) -> str:
    """``[[on_change]]`` blocks of ``tables`` (as :meth:`OnChange.table` gives them, or as written: a value may be
    ``{ value, unit }`` or ``{ path }``), ``set`` as one inline table so that the block reads back as written."""
    def inline(name: str, value: Any) -> str:
        if isinstance(value, Mapping):
            return f"{_toml_key(name)} = {{ {', '.join(inline(k, v) for k, v in value.items())} }}"
        return tomli_w.dumps({name: value}).strip()

    return "\n".join("[[on_change]]\n" + "".join(inline(k, v) + "\n" for k, v in table.items())
                     for table in tables)


def _toml_key(name: str) -> str:
    """``name`` as a TOML key (quoted when it has to be, as ``"force.n_flutes"``)."""
    return tomli_w.dumps({name: 0}).strip()[:-len(" = 0")]


@dataclass(frozen=True)
class Scenario:
    path: Path
    name: str
    description: str
    start_time: float
    stop_time: float
    output_interval: float
    base_step: float
    ticks_per_output: int  # output_interval / base step
    instances: tuple[FmuInstance, ...]  # in execution order
    recorded: RecordedData | None = field(repr=False, compare=False)
    inputs: tuple[RecordedInput, ...]
    connections: tuple[Connection, ...]
    outputs: tuple[Ref, ...]
    compare: tuple[Compare, ...]
    # the parameter-set files applied, in order: the file's own [scenario].parameter_sets (resolved against
    # its folder), then those load_scenario(..., parameter_sets=...) was given
    parameter_sets: tuple[Path, ...] = ()
    stepping: Stepping | None = None  # [stepping]: the variable communication step (None: every step fine)
    part: Part | None = None  # a whole-part scenario's [part], read (orchestrator/part/spec.py)
    alignment: Alignment | None = None  # [alignment]: comparisons on aligned times
    on_change: tuple[OnChange, ...] = ()  # [[on_change]]: parameter changes at events, in file order

    @property
    def execution_order(self) -> tuple[str, ...]:
        return tuple(inst.name for inst in self.instances)

    def instance(self, name: str) -> FmuInstance:
        return next(inst for inst in self.instances if inst.name == name)

    def variable(self, ref: Ref) -> Variable:
        return self.instance(ref.instance).variables[ref.variable]


class _Ctx(TomlAccess):
    """Typed access to this file's TOML values; errors are ScenarioErrors naming file and key."""

    error = ScenarioError


def _factor(from_unit: str, to_unit: str) -> float:
    # Identical strings need no table entry (e.g. "W.s/rad" is unknown to units.py).
    return 1.0 if from_unit == to_unit else conversion_factor(from_unit, to_unit)


def _variables(md: Any) -> dict[str, Variable]:
    out = {}
    for v in md.modelVariables:
        unit = v.unit or (v.declaredType.unit if v.declaredType is not None else None) or ""
        unit = "" if unit == "1" else unit  # the descriptions' dimensionless unit: none, as in models/
        display = v.displayUnit or (v.declaredType.displayUnit if v.declaredType is not None else None) or ""
        kind = _SUPPORTED_TYPES.get(v.type, v.type) if not v.dimensions else f"{_SUPPORTED_TYPES.get(v.type, v.type)}[]"
        bound = lambda x: float(x) if x is not None and kind in ("real", "int", "real[]") else None  # noqa: E731
        out[v.name] = Variable(v.name, v.valueReference, kind, v.causality, v.variability,
                               "bool" if kind == "bool" else unit, bound(v.min), bound(v.max),
                               display_unit="" if kind == "bool" else display)
    return {**out, **_arrays(md, out)}


_ELEMENT_RE = re.compile(r"^(?P<name>[^\[\]]+)\[(?P<index>\d+(?:,\d+)*)\]$")


def _arrays(md: Any, variables: Mapping[str, Variable]) -> dict[str, Variable]:
    """Arrays as the scenario addresses them: ``name`` the whole array (connected or recorded element by
    element), ``name[i,j]`` (1-based, row-major) its elements. FMI 3: from each Float64 variable with fixed
    <Dimension>s, its elements added; FMI 2: from the complete groups of scalars named ``name[i,j]``."""
    out: dict[str, Variable] = {}
    for v in md.modelVariables:
        whole = variables[v.name]
        if not v.dimensions or whole.type != "real[]" or any(d.start is None for d in v.dimensions):
            continue
        shape = tuple(int(d.start) for d in v.dimensions)
        names = tuple(f"{v.name}[{','.join(str(i + 1) for i in index)}]" for index in _row_major(shape))
        out[v.name] = replace(whole, shape=shape, elements=names)
        for k, name in enumerate(names):
            out[name] = replace(whole, name=name, type="real", array=v.name, element=k)
    groups: dict[str, list[tuple[tuple[int, ...], Variable]]] = {}
    for name, var in variables.items():
        match = _ELEMENT_RE.match(name)
        if match and var.type == "real" and match["name"] not in variables:
            groups.setdefault(match["name"], []).append((tuple(int(i) for i in match["index"].split(",")), var))
    for name, members in groups.items():
        shape = tuple(max(index[d] for index, _ in members) for d in range(len(members[0][0])))
        if any(len(index) != len(shape) for index, _ in members) or len(members) != math.prod(shape):
            continue  # not a complete array
        members.sort(key=lambda m: m[0])
        first = members[0][1]
        out[name] = replace(first, name=name, value_reference=-1, type="real[]", shape=shape,
                            elements=tuple(var.name for _, var in members))
    return out


def _row_major(shape: tuple[int, ...]) -> list[tuple[int, ...]]:
    indices: list[tuple[int, ...]] = [()]
    for n in shape:
        indices = [index + (i,) for index in indices for i in range(n)]
    return indices


def _load_fmu(ctx: _Ctx, name: str, table: dict, fmu_dir: Path) -> tuple[dict, Path, Any]:
    key = f"[fmus.{name}]"
    ctx.table(table, key, ("fmu", "fmi", "step_size", "parameters", "inputs"))
    fmu = ctx.string(table, key, "fmu")
    fmi = table.get("fmi", 3)
    if fmi not in (2, 3) or isinstance(fmi, bool):
        ctx.fail(f"{key}.fmi", f"must be 2 or 3, got {fmi!r}")
    if fmu.endswith(".fmu"):
        path = ctx.path.parent / fmu
    else:
        path = fmu_dir / (f"{fmu}.fmu" if fmi == 3 else f"{fmu}_fmi2.fmu")
    if not path.is_file():
        found = sorted(p.stem for p in fmu_dir.glob("*.fmu")) if fmu_dir.is_dir() else []
        where = (f"available in {fmu_dir}: {', '.join(found)}" if found else
                 f"{fmu_dir} holds no FMUs" if fmu_dir.is_dir() else
                 f"{fmu_dir} does not exist")
        how = "" if fmu.endswith(".fmu") else f"; {BUILD_HINT}"
        ctx.fail(f"{key}.fmu", f"FMU {fmu!r} not found: looked for {path}; {where}{how}")
    try:
        md = read_model_description(str(path))
    except Exception as exc:  # fmpy raises plain Exceptions for broken archives
        ctx.fail(f"{key}.fmu", f"cannot read the model description of {path}: {exc}")
    if not md.fmiVersion.startswith(f"{fmi}."):
        ctx.fail(f"{key}.fmi", f"{path} is an FMI {md.fmiVersion} FMU, not FMI {fmi}")
    if md.coSimulation is None:
        ctx.fail(f"{key}.fmu", f"{path} does not support co-simulation")
    binary = (f"binaries/{fmpy.platform_tuple if fmi == 3 else fmpy.platform}/"
              f"{md.coSimulation.modelIdentifier}{fmpy.sharedLibraryExtension}")
    with zipfile.ZipFile(path) as archive:
        names = archive.namelist()
    if binary not in names:  # else fmpy fails at instantiation with a bare Exception
        folders = sorted({n.split("/")[1] for n in names if n.startswith("binaries/") and n.count("/") >= 2})
        ctx.fail(f"{key}.fmu", f"{path} has no binary for this platform ({binary}); its binaries/ holds "
                               f"{', '.join(folders) if folders else 'nothing'}")
    return table, path, md


def _parameters(ctx: _Ctx, inst: str, table: Any, variables: Mapping[str, Variable], model: str,
                causality: str = "parameter", key: str | None = None) -> dict:
    """``[fmus.<inst>].parameters`` (or ``.inputs`` with causality "input"): values by name, SI.
    ``key``: the TOML key for messages when the table is not the scenario's own."""
    section = "parameters" if causality == "parameter" else "inputs"
    key = key or f"[fmus.{inst}].{section}"
    if not isinstance(table, dict):
        ctx.fail(key, f"expected a table, got {table!r}")
    known = [v.name for v in variables.values() if v.causality == causality]
    values: dict[str, float | bool | int] = {}
    for name, raw in table.items():
        k = f"{key}.{name}"
        var = variables.get(name)
        if var is None or var.causality != causality:
            what = "unknown variable" if var is None else f"{var.causality} variable"
            ctx.fail(k, f"{what} {name!r} in {model}; known {section}: {', '.join(known)}")
        if var.type not in ("real", "bool", "int", "string") or var.array:
            what = f"an element of the FMI 3 array {var.array!r}" if var.array else f"of unsupported type {var.type}"
            ctx.fail(k, f"{causality} {name!r} is {what}: arrays are set from connections only")
        if var.type == "string":  # text as given, or { path = "..." }: a file relative to the scenario
            if isinstance(raw, dict):
                ctx.table(raw, k, ("path",))
                resolved = (ctx.path.parent / ctx.string(raw, k, "path")).resolve()
                if not resolved.exists():
                    ctx.fail(f"{k}.path", f"no file {resolved}")
                _check_file_parameter(ctx, f"{k}.path", model, name, resolved)
                raw = str(resolved)
            elif isinstance(raw, str) and raw and (Path(raw).exists() or Path(raw).is_symlink()):  # a path, as given
                _check_file_parameter(ctx, k, model, name, Path(raw))
            if not isinstance(raw, str):
                ctx.fail(k, f"{name!r} is a String: give text or {{ path = \"...\" }}, got {raw!r}")
            values[name] = raw
            continue
        unit = None
        if isinstance(raw, dict):
            ctx.table(raw, k, ("value", "unit"))
            unit = ctx.string(raw, k, "unit")
            raw = raw.get("value")
        if var.type == "bool":
            if not isinstance(raw, bool) or unit not in (None, "bool"):
                ctx.fail(k, f"{name!r} is Boolean: give true or false, got {raw!r}")
            values[name] = raw
            continue
        if var.type == "int":
            if isinstance(raw, bool) or not isinstance(raw, int) or unit is not None:
                ctx.fail(k, f"{name!r} is an integer: give a whole number without unit, got {raw!r}")
            if (var.min is not None and raw < var.min) or (var.max is not None and raw > var.max):
                ctx.fail(k, f"{raw!r} is outside the range [{var.min:g}, {var.max:g}] that {model} allows "
                            f"for {name!r}")
            values[name] = raw
            continue
        if isinstance(raw, bool) or not isinstance(raw, (int, float)) or not math.isfinite(raw):
            ctx.fail(k, f"expected a finite number, got {raw!r}")
        try:
            values[name] = value = float(raw) * (1.0 if unit is None else _factor(unit, var.unit))
        except UnitError as exc:
            ctx.fail(k, f"unit {unit!r} does not fit {name!r} (unit {var.unit!r}): {exc}")
        if (var.min is not None and value < var.min) or (var.max is not None and value > var.max):
            unit_text = f" {var.unit}" if var.unit else ""
            ctx.fail(k, f"{value!r}{unit_text} is outside the range [{var.min!r}, {var.max!r}]"
                        f"{unit_text} that {model} allows for {name!r}")
    return values


def _base_step(ctx: _Ctx, steps: dict[str, float]) -> tuple[float, dict[str, int]]:
    """The gcd of the step sizes and each step as a multiple of it."""
    # Rationals of the decimal values (to 1e-9 s), so that 0.1 and 0.3 give exactly 0.1.
    fracs = {n: Fraction(repr(s)).limit_denominator(10**9) for n, s in steps.items()}
    denominator = math.lcm(*(f.denominator for f in fracs.values()))
    base = Fraction(math.gcd(*(int(f * denominator) for f in fracs.values())), denominator)
    ratios = {n: int(f / base) for n, f in fracs.items()}
    worst = max(ratios, key=ratios.__getitem__)
    off_grid = any(abs(steps[n] / float(base) - r) > 1e-6 * r for n, r in ratios.items())
    if off_grid or ratios[worst] > MAX_STEP_RATIO:
        listing = ", ".join(f"{n}: {s!r}" for n, s in steps.items())
        ctx.fail(f"[fmus.{worst}].step_size",
                 f"step sizes ({listing}) are not integer multiples of a common base step of at "
                 f"least 1/{MAX_STEP_RATIO} of the largest (their gcd is {float(base)!r} s)")
    return float(base), ratios


def _parameter_set(ctx: _Ctx, key: str, path: Path, instances: Mapping[str, FmuInstance]) -> dict[str, dict]:
    """The values of one parameter-set file by instance (SI), checked like the scenario's own;
    any problem is reported under ``key`` of the scenario, naming the set file and its key."""
    own = _Ctx(path)
    try:
        _, doc = own.parse("parameter set file")
        own.table(doc, "", ("description", "source", "parameters"))
        own.string(doc, "", "description", "")
        if not isinstance(doc.get("source", {}), dict):
            own.fail("[source]", "expected a table")
        tables = doc.get("parameters")
        if not isinstance(tables, dict) or not tables:
            own.fail("[parameters]", "expected [parameters.<instance>] tables of values")
        values = {}
        for name, table in tables.items():
            if name not in instances:
                own.fail(f"[parameters.{name}]", f"unknown instance {name!r}; instances: {', '.join(instances)}")
            inst = instances[name]
            values[name] = _parameters(own, name, table, inst.variables, inst.model_identifier,
                                       key=f"[parameters.{name}]")
    except ScenarioError as exc:
        ctx.fail(key, str(exc))
    return values


def _check_file_parameter(ctx: _Ctx, key: str, model: str, name: str, path: Path) -> None:
    """A String parameter that names a file the FMU parses (the Interpolator's program and tool table): a regular
    file of that kind, else an error under ``key`` without the file's content (orchestrator/gcode/recognise.py)."""
    check = FILE_PARAMETERS.get((model, name))
    if check is not None:
        try:
            check(path)
        except NotThatFileError as exc:
            ctx.fail(key, str(exc))


def _recorded(ctx: _Ctx, table: Any, recording: Path | None = None, until: float | None = None) -> RecordedData:
    key = "[recorded]"
    ctx.table(table, key, ("file", "sample_period", "time_column", "time_unit", "channels", "checks"))
    file = ctx.path.parent / ctx.string(table, key, "file") if recording is None else recording
    sample_period = ctx.number(table, key, "sample_period", None, positive=True)
    time_column = ctx.string(table, key, "time_column", None)
    time_unit = ctx.string(table, key, "time_unit", "s")
    if (sample_period is None) == (time_column is None):
        ctx.fail(key, "give exactly one of sample_period and time_column")
    channels = table.get("channels", {})
    if not isinstance(channels, dict):
        ctx.fail("[recorded.channels]", f"expected a table, got {channels!r}")
    specs = []
    for name, spec in channels.items():
        k = f"[recorded.channels].{name}"
        ctx.table(spec, k, ("column", "unit", "above", "match"))
        match = ctx.string(spec, k, "match", None)
        specs.append(ChannelSpec(name, ctx.string(spec, k, "column"),
                                 ctx.string(spec, k, "unit", "bool" if match else "1"),
                                 above=ctx.number(spec, k, "above", None), match=match))
    try:
        data = load_recorded(file, specs, time_column=time_column, time_unit=time_unit,
                             sample_period=sample_period, until=until)
    except RecordedDataError as exc:
        culprit = next((s.name for s in specs if f"channel {s.name!r}" in str(exc)), None)
        ctx.fail(f"[recorded.channels].{culprit}" if culprit else
                 "[recorded].time_column" if "time column" in str(exc) else "[recorded].file", str(exc))
    if "checks" in table:
        data.check = check_table(ctx.fail, table["checks"], data)
    return data


def _resolve(ctx: _Ctx, key: str, text: Any, instances: Mapping[str, FmuInstance],
             causality: str | None, whole_arrays: bool = False,
             types: Sequence[str] = ("real", "bool")) -> tuple[Ref, Variable]:
    """Look up "instance.variable"; ``causality`` None accepts any; ``whole_arrays``: an array may be named;
    ``types``: the accepted scalar types."""
    ref = Ref.parse(text, key, ctx.fail)
    inst_name, var_name = ref.instance, ref.variable
    inst = instances.get(inst_name)
    if inst is None:
        ctx.fail(key, f"unknown instance {inst_name!r}; instances: {', '.join(instances)}")
    candidates = [v.name for v in inst.variables.values()
                  if causality is None or v.causality == causality]
    var = inst.variables.get(var_name)
    what = f"{causality}s" if causality else "variables"
    if var is None:
        ctx.fail(key, f"unknown variable {var_name!r} in {inst_name} ({inst.model_identifier}); "
                      f"known {what}: {', '.join(candidates)}")
    if causality is not None and var.causality != causality:
        ctx.fail(key, f"{text} is {_a(var.causality)}, not {_a(causality)}; {what} of {inst_name}: "
                      f"{', '.join(candidates)}")
    if var.type == "real[]" and whole_arrays:
        return ref, var
    if var.type == "real[]":
        ctx.fail(key, f"{text} is {_what(var)}: connect it to an array input of the same shape "
                      f"([[connections]]), record it whole, or name one element, e.g. {var.elements[0]}")
    if var.type not in types:
        names = {"real": "Real/Float64", "bool": "Boolean", "int": "Integer/Int32"}
        ctx.fail(key, f"{text} has unsupported type {var.type} (only {' and '.join(names[x] for x in types)})")
    return ref, var


def _shape(var: Variable) -> str:
    return "x".join(str(n) for n in var.shape)


def _resolve_all(ctx: _Ctx, key: str, text: Any, instances: Mapping[str, FmuInstance],
                 causality: str | None, types: Sequence[str] = ("real", "bool")) -> list[tuple[Ref, Variable]]:
    """Like _resolve, but a whole array stands for its elements, row-major."""
    return _elements(instances, *_resolve(ctx, key, text, instances, causality, whole_arrays=True, types=types))


def _elements(instances: Mapping[str, FmuInstance], ref: Ref, var: Variable) -> list[tuple[Ref, Variable]]:
    """A scalar itself; a whole array its elements, row-major."""
    if var.type != "real[]":
        return [(ref, var)]
    variables = instances[ref.instance].variables
    return [(Ref(ref.instance, name), variables[name]) for name in var.elements]


def _settable_element(ctx: _Ctx, key: str, ref: Ref, var: Variable) -> None:
    """FMI 3 sets an array whole: one of its elements cannot be fed on its own."""
    if var.array:
        ctx.fail(key, f"{ref} is an element of the FMI 3 array {ref.instance}.{var.array}, which is set whole: "
                      f"connect the whole array (to = \"{ref.instance}.{var.array}\") from an array output")


def _a(word: str) -> str:
    return f"an {word}" if word[0] in "aeiou" else f"a {word}"


def _what(var: Variable) -> str:
    return f"an array of {_shape(var)} values" if var.shape else "a scalar"


def _array(ctx: _Ctx, doc: dict, name: str, allowed: Sequence[str]) -> list[tuple[str, dict]]:
    items = doc.get(name, [])
    if not isinstance(items, list):
        ctx.fail(f"[[{name}]]", "expected an array of tables ([[...]])")
    return [(f"[[{name}]][{i}]", ctx.table(item, f"[[{name}]][{i}]", allowed))
            for i, item in enumerate(items)]


def _execution_order(ctx: _Ctx, names: list[str], conns: list[tuple[str, Connection]]) -> list[str]:
    edges = [(key, c) for key, c in conns if not c.delay]
    placed: list[str] = []
    while len(placed) < len(names):
        ready = [n for n in names if n not in placed and not any(
            c.target.instance == n and c.source.instance not in placed for _, c in edges)]
        if not ready:
            _report_loop(ctx, [n for n in names if n not in placed], edges)
        placed.append(ready[0])
    return placed


def _report_loop(ctx: _Ctx, remaining: list[str], edges: list[tuple[str, Connection]]) -> NoReturn:
    # Every remaining instance has an incoming edge from another remaining one: walk
    # backwards along them until an instance repeats; that stretch is a cycle.
    path: list[tuple[str, Connection]] = []
    node = remaining[0]
    visited = [node]
    while True:
        key, conn = next((k, c) for k, c in edges
                         if c.target.instance == node and c.source.instance in remaining)
        path.append((key, conn))
        node = conn.source.instance
        if node in visited:
            cycle = path[visited.index(node):][::-1]
            break
        visited.append(node)
    listing = ", ".join(f"{c.source} -> {c.target} ({k})" for k, c in cycle)
    ctx.fail(cycle[0][0], f"algebraic loop between instances through {listing}; set "
                          f"delay = true on one of these connections to break it")


def load_scenario(path: str | Path, fmu_dir: str | Path, parameter_sets: Sequence[str | Path] = (), *,
                  recording: str | Path | None = None, document: Mapping[str, Any] | None = None) -> Scenario:
    """Parse and validate a scenario file; FMU names are resolved in ``fmu_dir``. ``parameter_sets``:
    parameter-set files applied after the scenario's own ``[scenario].parameter_sets``. ``recording``: a
    recording read instead of ``[recorded].file`` (another run of the same machine and logger: the same
    columns, channels and checks). ``document``: the file's TOML as read and then edited (the feed optimizer's
    part file with another program), used instead of reading ``path``; paths in it are still relative to
    ``path``'s folder and messages still name ``path``."""
    path, fmu_dir = Path(path), Path(fmu_dir)
    ctx = _Ctx(path)
    doc = copy.deepcopy(dict(document)) if document is not None else ctx.document("scenario")[1]
    part = None
    if "part" in doc:  # a whole-part scenario: [part] expanded into the explicit instances (docs/part.md)
        from milling_twin.orchestrator.part.expand import expand_document
        doc, part = expand_document(ctx, doc, fmu_dir)
    ctx.table(doc, "", ("scenario", "fmus", "recorded", "inputs", "connections", "outputs", "compare",
                        "stepping", "alignment", "on_change"))

    sc = ctx.table(doc.get("scenario"), "[scenario]", (
        "name", "description", "start_time", "stop_time", "output_interval", "parameter_sets"))
    name = ctx.string(sc, "[scenario]", "name")
    _check_run_name(ctx, "[scenario].name", name)
    start = ctx.number(sc, "[scenario]", "start_time", 0.0)
    output_interval = ctx.number(sc, "[scenario]", "output_interval", positive=True)

    fmus = doc.get("fmus")
    if not isinstance(fmus, dict) or not fmus:
        ctx.fail("[fmus]", "define at least one FMU instance as [fmus.<name>]")
    loaded = {}
    for inst in fmus:
        if not _NAME_RE.match(inst) or "." in inst:
            ctx.fail(f"[fmus.{inst}]", "instance names use only letters, digits, '_' and '-'")
        table, fmu_path, md = _load_fmu(ctx, inst, fmus[inst], fmu_dir)
        loaded[inst] = (table, fmu_path, md, ctx.number(table, f"[fmus.{inst}]", "step_size", positive=True))
    base, ratios = _base_step(ctx, {n: v[3] for n, v in loaded.items()})
    ticks_per_output = round(output_interval / base)
    if ticks_per_output < 1 or abs(output_interval / base - ticks_per_output) > 1e-6 * ticks_per_output:
        ctx.fail("[scenario].output_interval",
                 f"{output_interval!r} s is not an integer multiple of the base step {base!r} s")
    instances: dict[str, FmuInstance] = {}
    for inst, (table, fmu_path, md, step) in loaded.items():
        variables = _variables(md)
        model = md.coSimulation.modelIdentifier
        params = _parameters(ctx, inst, table.get("parameters", {}), variables, model)
        constants = _parameters(ctx, inst, table.get("inputs", {}), variables, model, "input")
        instances[inst] = FmuInstance(inst, fmu_path, int(md.fmiVersion[0]), step, ratios[inst],
                                      model, md.guid, params, variables, constants)
    own_sets = sc.get("parameter_sets", [])
    if not isinstance(own_sets, list) or not all(isinstance(s, str) for s in own_sets):
        ctx.fail("[scenario].parameter_sets", f"expected a list of file names, got {own_sets!r}")
    applied_sets = ([(f"[scenario].parameter_sets[{i}]", path.parent / s) for i, s in enumerate(own_sets)]
                    + [(f"parameter_sets[{i}]", Path(s)) for i, s in enumerate(parameter_sets)])
    for key, set_path in applied_sets:
        for inst, values in _parameter_set(ctx, key, set_path, instances).items():
            instances[inst] = replace(instances[inst], parameters={**instances[inst].parameters, **values})

    if recording is not None and "recorded" not in doc:
        ctx.fail("[recorded]", f"a recording ({recording}) is given, but the scenario has no [recorded] table")
    # a run ending at stop_time reads the recording up to there (not when [alignment] maps other times onto it)
    until = ctx.number(sc, "[scenario]", "stop_time", None) if "alignment" not in doc else None
    recorded = _recorded(ctx, doc["recorded"], None if recording is None else Path(recording), until) \
        if "recorded" in doc else None
    if "stop_time" in sc:
        stop = ctx.number(sc, "[scenario]", "stop_time")
    elif recorded is not None:
        stop = recorded.t_end
    else:
        ctx.fail("[scenario].stop_time", "missing required key (no [recorded] data to default to)")
    if stop < start + output_interval:
        ctx.fail("[scenario].stop_time", f"{stop!r} must be at least start_time + output_interval")

    fed: dict[Ref, str] = {Ref(i.name, n): f"[fmus.{i.name}].inputs.{n}" for i in instances.values()
                           for n in i.inputs}

    def feed(key: str, ref: Ref) -> None:
        if ref in fed:
            ctx.fail(f"{key}.to", f"input {ref} is already fed by {fed[ref]}")
        fed[ref] = key

    inputs = []
    for key, item in _array(ctx, doc, "inputs", ("from", "to", "interpolation")):
        channel = ctx.string(item, key, "from")
        if recorded is None or channel not in recorded.channels:
            known = ", ".join(recorded.channels) if recorded else "none (no [recorded] section)"
            ctx.fail(f"{key}.from", f"unknown recorded channel {channel!r}; channels: {known}")
        ref, var = _resolve(ctx, f"{key}.to", item.get("to"), instances, "input")
        _settable_element(ctx, f"{key}.to", ref, var)
        interpolation = ctx.string(item, key, "interpolation", "linear")
        if interpolation not in ("linear", "hold"):
            ctx.fail(f"{key}.interpolation", f"expected \"linear\" or \"hold\", got {interpolation!r}")
        try:
            factor = _factor(recorded.units[channel], var.unit)
        except UnitError as exc:
            ctx.fail(f"{key}.to", f"channel {channel!r} ({recorded.units[channel]}) cannot feed "
                                  f"{ref} ({var.unit or 'no unit'}): {exc}")
        feed(key, ref)
        inputs.append(RecordedInput(channel, ref, interpolation, factor))
    if inputs:
        lo, hi = recorded.t_start, recorded.t_end
        if start < lo - 1e-9 or stop > hi + 1e-9:
            ctx.fail("[scenario].stop_time" if stop > hi else "[scenario].start_time",
                     f"simulated time [{start!r}, {stop!r}] s exceeds the recorded data [{lo!r}, {hi!r}] s")

    conns = []
    for key, item in _array(ctx, doc, "connections", ("from", "to", "delay")):
        src_ref, src_var = _resolve(ctx, f"{key}.from", item.get("from"), instances, "output", whole_arrays=True)
        dst_ref, dst_var = _resolve(ctx, f"{key}.to", item.get("to"), instances, "input", whole_arrays=True)
        sources, targets = _elements(instances, src_ref, src_var), _elements(instances, dst_ref, dst_var)
        if len(sources) > 1 or len(targets) > 1:  # an array to an array of the same shape, element by element
            if src_var.shape != dst_var.shape:
                ctx.fail(f"{key}.to", f"shape mismatch: {src_ref} is {_what(src_var)}, {dst_ref} "
                                      f"is {_what(dst_var)}")
        elif targets[0][1].array:
            _settable_element(ctx, f"{key}.to", *targets[0])
        delay = item.get("delay", False)
        if not isinstance(delay, bool):
            ctx.fail(f"{key}.delay", f"expected true or false, got {delay!r}")
        for (src, svar), (dst, dvar) in zip(sources, targets):
            try:
                factor = _factor(svar.unit, dvar.unit)
            except UnitError as exc:
                ctx.fail(f"{key}.to", f"unit mismatch: {src} ({svar.unit or 'no unit'}) -> "
                                      f"{dst} ({dvar.unit or 'no unit'}): {exc}")
            feed(key, dst)
            conns.append((key, Connection(src, dst, delay, factor)))

    out_table = ctx.table(doc.get("outputs", {}), "[outputs]", ("record",))
    if "record" in out_table:
        names = out_table["record"]
        if not isinstance(names, list):
            ctx.fail("[outputs].record", "expected an array of \"instance.variable\" strings")
        outputs = [ref for i, s in enumerate(names)
                   for ref, _ in _resolve_all(ctx, f"[outputs].record[{i}]", s, instances, None, RECORDABLE_TYPES)]
    else:
        outputs = [Ref(i.name, v.name) for i in instances.values()
                   for v in i.variables.values() if v.causality == "output" and v.type in RECORDABLE_TYPES]

    compares = []
    for key, item in _array(ctx, doc, "compare", ("simulated", "recorded", "unit")):
        ref, var = _resolve(ctx, f"{key}.simulated", item.get("simulated"), instances, None)
        channel = ctx.string(item, key, "recorded")
        if recorded is None or channel not in recorded.channels:
            known = ", ".join(recorded.channels) if recorded else "none (no [recorded] section)"
            ctx.fail(f"{key}.recorded", f"unknown recorded channel {channel!r}; channels: {known}")
        display = ctx.string(item, key, "unit", None)
        try:
            _factor(recorded.units[channel], var.unit)
        except UnitError as exc:
            ctx.fail(f"{key}.recorded", f"cannot compare {ref} ({var.unit or 'no unit'}) with "
                                        f"channel {channel!r} ({recorded.units[channel]}): {exc}")
        try:
            if display is not None:
                _factor(var.unit, display)
        except UnitError as exc:
            ctx.fail(f"{key}.unit", f"display unit {display!r} does not fit {ref}: {exc}")
        if ref not in outputs:
            outputs.append(ref)
        compares.append(Compare(ref, channel, display))

    alignment = _alignment(ctx, doc["alignment"], instances, recorded) if "alignment" in doc else None
    if alignment is not None:
        outputs += [ref for ref in alignment.simulated if ref not in outputs]
    order = _execution_order(ctx, list(instances), conns)
    stepping = _stepping(ctx, doc["stepping"], [instances[n] for n in order], base,
                         {n: v[2] for n, v in loaded.items()}) if "stepping" in doc else None
    on_change = _on_change(ctx, doc, instances, stepping)
    return Scenario(
        path=path, name=name, description=ctx.string(sc, "[scenario]", "description", ""),
        start_time=start, stop_time=stop, output_interval=output_interval, base_step=base,
        ticks_per_output=ticks_per_output, instances=tuple(instances[n] for n in order),
        recorded=recorded, inputs=tuple(inputs), connections=tuple(c for _, c in conns),
        outputs=tuple(dict.fromkeys(outputs)), compare=tuple(compares),
        parameter_sets=tuple(set_path for _, set_path in applied_sets), stepping=stepping, part=part,
        alignment=alignment, on_change=on_change,
    )


def _alignment(ctx: _Ctx, table: Any, instances: Mapping[str, FmuInstance],
               recorded: RecordedData | None) -> Alignment:
    """``[alignment]``, checked against the recorded channels and the instances' outputs."""
    from milling_twin.orchestrator.align import METHODS
    key = "[alignment]"
    ctx.table(table, key, ("recorded", "simulated", "method"))
    if recorded is None:
        ctx.fail(key, "aligns the recording with the simulation: add a [recorded] section")
    channels, names = table.get("recorded"), table.get("simulated")
    for field_name, value in (("recorded", channels), ("simulated", names)):
        if not (isinstance(value, list) and 2 <= len(value) <= 3 and all(isinstance(v, str) for v in value)):
            ctx.fail(f"{key}.{field_name}", f"expected 2 or 3 names (x, y[, z]), got {value!r}")
    if len(channels) != len(names):
        ctx.fail(f"{key}.simulated", f"{len(names)} outputs for {len(channels)} recorded channels: give one per axis")
    refs = []
    for i, (channel, name) in enumerate(zip(channels, names)):
        if channel not in recorded.channels:
            ctx.fail(f"{key}.recorded[{i}]", f"unknown recorded channel {channel!r}; channels: "
                                             f"{', '.join(recorded.channels)}")
        ref, var = _resolve(ctx, f"{key}.simulated[{i}]", name, instances, "output", types=("real",))
        try:
            _factor(recorded.units[channel], "m")
            _factor(var.unit, "m")
        except UnitError:
            ctx.fail(f"{key}.simulated[{i}]", f"aligns positions: {channel!r} ({recorded.units[channel]}) and "
                                              f"{ref} ({var.unit or 'no unit'}) must both be lengths")
        refs.append(ref)
    method = ctx.string(table, key, "method", "multiscale")
    if method not in METHODS:
        ctx.fail(f"{key}.method", f"{method!r}: expected one of {', '.join(METHODS)}")
    return Alignment(tuple(channels), tuple(refs), method)


def _stepping(ctx: _Ctx, table: Any, order: Sequence[FmuInstance], base: float,
              model_descriptions: Mapping[str, Any]) -> Stepping:
    """``[stepping]``, checked against the instances (in execution order) and the base step."""
    key = "[stepping]"
    ctx.table(table, key, ("coarse_step", "variable", "fine_when", "hold"))
    coarse = ctx.number(table, key, "coarse_step", positive=True)
    ticks = round(coarse / base)
    if ticks < 1 or abs(coarse / base - ticks) > 1e-6 * ticks:
        ctx.fail(f"{key}.coarse_step", f"{coarse!r} s is not an integer multiple of the base step {base!r} s")
    hold_intervals = _hold_intervals(ctx, table, key, coarse)
    by_name = {inst.name: inst for inst in order}
    position = {inst.name: i for i, inst in enumerate(order)}
    names = table.get("variable")
    if not isinstance(names, list) or not names:
        ctx.fail(f"{key}.variable", f"expected a non-empty list of instance names, got {names!r}")
    for i, name in enumerate(names):
        k = f"{key}.variable[{i}]"
        if not isinstance(name, str) or name not in by_name:
            ctx.fail(k, f"unknown instance {name!r}; instances: {', '.join(by_name)}")
        if name in names[:i]:
            ctx.fail(k, f"instance {name!r} is listed twice")
        inst = by_name[name]
        if ticks % inst.ticks_per_step:
            ctx.fail(k, f"instance {name!r} steps at {inst.step_size!r} s, which does not divide coarse_step "
                        f"{coarse!r} s")
        if not model_descriptions[name].coSimulation.canHandleVariableCommunicationStepSize:
            ctx.fail(k, f"instance {name!r}: {inst.path.name} declares canHandleVariableCommunicationStepSize="
                        f"\"false\" in its model description, so it cannot take a coarse step")
    first = min(names, key=position.__getitem__)
    conditions = table.get("fine_when")
    if not isinstance(conditions, list) or not conditions:
        ctx.fail(f"{key}.fine_when", f"expected a non-empty list of conditions "
                                     f"({{ output = \"instance.variable\", above = ... }}), got {conditions!r}")
    gates = []
    for i, item in enumerate(conditions):
        k = f"{key}.fine_when[{i}]"
        ctx.table(item, k, ("output", "above", "below", "is"))
        ref, var = _resolve(ctx, f"{k}.output", item.get("output"), by_name, "output")
        inst = by_name[ref.instance]
        if inst.ticks_per_step != ticks:
            ctx.fail(f"{k}.output", f"instance {ref.instance!r} steps at {inst.step_size!r} s, not at coarse_step "
                                    f"{coarse!r} s: a condition's output must come from an instance stepping once "
                                    "per coarse interval")
        if position[ref.instance] >= position[first]:
            ctx.fail(f"{k}.output", f"instance {ref.instance!r} does not precede the variable instance {first!r} "
                                    f"in the execution order ({', '.join(position)})")
        senses = [s for s in ("above", "below", "is") if s in item]
        if len(senses) != 1:
            ctx.fail(k, f"give exactly one of above, below (Real outputs) and is (Boolean outputs), got "
                        f"{', '.join(senses) or 'none'}")
        sense, raw = senses[0], item[senses[0]]
        if var.type == "bool":
            if sense != "is" or not isinstance(raw, bool):
                ctx.fail(f"{k}.{sense}", f"{ref} is Boolean: give is = true or is = false")
            gates.append(FineWhen(ref, sense, 1.0 if raw else 0.0))
            continue
        if sense == "is":
            ctx.fail(f"{k}.is", f"{ref} is Real: give above or below a threshold")
        raw, unit = _number_and_unit(ctx, f"{k}.{sense}", raw, "a finite number")
        try:
            threshold = float(raw) * (1.0 if unit is None else _factor(unit, var.unit))
        except UnitError as exc:
            ctx.fail(f"{k}.{sense}", f"unit {unit!r} does not fit {ref} ({var.unit or 'no unit'}): {exc}")
        gates.append(FineWhen(ref, sense, threshold))
    return Stepping(coarse, ticks, tuple(sorted(names, key=position.__getitem__)), tuple(gates), hold_intervals)


def _number_and_unit(ctx: _Ctx, key: str, raw: Any, expected: str) -> tuple[float, str | None]:
    """A number as written, or ``{ value, unit }``: (the finite number, its unit or None); else an error at ``key``
    saying it expected ``expected`` and what it got (the value itself when written in a table)."""
    unit = None
    if isinstance(raw, dict):
        ctx.table(raw, key, ("value", "unit"))
        unit = ctx.string(raw, key, "unit")
        raw = raw.get("value")
    if isinstance(raw, bool) or not isinstance(raw, (int, float)) or not math.isfinite(raw):
        ctx.fail(key, f"expected {expected} or {{ value, unit }}, got {raw!r}")
    return float(raw), unit


def hold_intervals(hold: float, coarse_step: float) -> int:
    """A ``[stepping].hold`` of ``hold`` s in coarse intervals of ``coarse_step`` s: rounded up, at least 1."""
    return max(1, math.ceil(hold / coarse_step * (1.0 - 1e-9)))


def _hold_intervals(ctx: _Ctx, table: Mapping[str, Any], key: str, coarse: float) -> int:
    """``[stepping].hold`` in whole coarse intervals, rounded up (1 without it)."""
    if "hold" not in table:
        return 1
    k = f"{key}.hold"
    raw, unit = _number_and_unit(ctx, k, table["hold"], "a finite number of seconds")
    try:
        hold = float(raw) * (1.0 if unit is None else _factor(unit, "s"))
    except UnitError as exc:
        ctx.fail(k, f"unit {unit!r} is not a time: {exc}")
    if hold < coarse * (1.0 - 1e-9):
        ctx.fail(k, f"{hold!r} s is shorter than coarse_step {coarse!r} s: the interval in which a condition "
                    "stops holding (the tool leaves material) must be fine")
    intervals = hold_intervals(hold, coarse)
    if intervals > 2**31 - 1:
        ctx.fail(k, f"{hold!r} s is {intervals} coarse intervals, more than 2^31 - 1")
    return intervals


def _on_change(ctx: _Ctx, doc: dict, instances: Mapping[str, FmuInstance],
               stepping: Stepping | None) -> tuple[OnChange, ...]:
    """``[[on_change]]``, checked against the instances (and ``[stepping]``: a trigger keeps its own step grid)."""
    entries = []
    for key, item in _array(ctx, doc, "on_change", ("output", "equals", "set")):
        ref, var = _resolve(ctx, f"{key}.output", item.get("output"), instances, "output",
                            types=("real", "bool", "int"))
        if var.type == "real":
            ctx.fail(f"{key}.output", f"{ref} is a Real/Float64 output: a trigger must be an Int32 or Boolean "
                                      "output (a value that changes in steps)")
        if stepping is not None and ref.instance in stepping.variable:
            ctx.fail(f"{key}.output", f"instance {ref.instance!r} is a variable instance of [stepping]: a trigger's "
                                      "instance must keep its own step grid")
        if "equals" not in item:
            ctx.fail(f"{key}.equals", "missing required key: the value that fires the entry")
        equals = item["equals"]
        if var.type == "bool" and not isinstance(equals, bool):
            ctx.fail(f"{key}.equals", f"{ref} is Boolean: give equals = true or false, got {equals!r}")
        if var.type == "int" and (isinstance(equals, bool) or not isinstance(equals, int)
                                  or not -2**31 <= equals < 2**31):
            ctx.fail(f"{key}.equals", f"{ref} is an Int32: give a whole number, got {equals!r}")
        table = item.get("set")
        if not isinstance(table, dict) or not table:
            ctx.fail(f"{key}.set", f"expected a table of at least one \"instance.variable\" = value, got {table!r}")
        values = []
        for name, raw in table.items():
            k = f"{key}.set.{_toml_key(name)}"
            target = Ref.parse(name, k, ctx.fail)
            inst = instances.get(target.instance)
            if inst is None:
                ctx.fail(k, f"unknown instance {target.instance!r}; instances: {', '.join(instances)}")
            try:  # the values of [fmus.<instance>.parameters], converted and checked by the same code
                value = _parameters(ctx, inst.name, {target.variable: raw}, inst.variables,
                                    inst.model_identifier)[target.variable]
            except ScenarioError as exc:
                ctx.fail(k, exc.detail)
            variability = inst.variables[target.variable].variability
            if variability != "tunable":
                ctx.fail(k, f"{target} is a {variability} parameter of {inst.model_identifier}: only tunable "
                            "parameters may change during a run")
            values.append((target, value))
        entries.append(OnChange(ref, equals, tuple(values)))
    return tuple(entries)


def _check_run_name(ctx: _Ctx, key: str, name: str) -> None:
    """``name`` names the run's folder (``<out>/<name>/``): letters, digits, '_', '-', '.' and one safe path
    component (:mod:`milling_twin.orchestrator.safe_names`: not ``.`` or ``..``, ...)."""
    if not _NAME_RE.match(name):
        ctx.fail(key, f"{name!r}: use only letters, digits, '_', '-' and '.'")
    problem = name_problem(name)
    if problem is not None:
        ctx.fail(key, f"{name!r} {problem}: it names the run's folder <out>/<name>/")


def with_values(scenario: Scenario, values: Mapping[str | Ref, Any], *, name: str | None = None) -> Scenario:
    """A copy of ``scenario`` with parameters or constant inputs changed, checked like the file's own
    (causality, type, unit, range). ``values``: ``{"instance.variable": value}`` (or a :class:`Ref` as the
    key), a plain number in the variable's SI unit or ``{"value": ..., "unit": ...}``. ``name`` renames
    the run (its folder), so that the runs of a sweep do not overwrite each other."""
    ctx = _Ctx(scenario.path)
    fed = {i.target for i in scenario.inputs} | {c.target for c in scenario.connections}
    names = [inst.name for inst in scenario.instances]
    grouped: dict[str, dict[str, dict[str, Any]]] = {}
    for key, value in values.items():
        where = f"with_values[{str(key)!r}]"
        ref = Ref.parse(key, where, ctx.fail)
        if ref.instance not in names:
            ctx.fail(where, f"unknown instance {ref.instance!r}; instances: {', '.join(names)}")
        var = scenario.instance(ref.instance).variables.get(ref.variable)
        causality = var.causality if var is not None else "parameter"
        if causality == "input" and ref in fed:
            ctx.fail(where, "this input is fed by [[inputs]] or [[connections]]")
        grouped.setdefault(ref.instance, {}).setdefault(causality, {})[ref.variable] = value
    instances = []
    for inst in scenario.instances:
        changes = grouped.get(inst.name, {})
        parameters = dict(inst.parameters)
        inputs = dict(inst.inputs)
        for causality, table in changes.items():
            checked = _parameters(ctx, inst.name, table, inst.variables, inst.model_identifier,
                                  "input" if causality == "input" else "parameter")
            (inputs if causality == "input" else parameters).update(checked)
        instances.append(replace(inst, parameters=parameters, inputs=inputs))
    if name is not None and not _NAME_RE.match(name):
        ctx.fail("with_values(name)", f"{name!r}: use letters, digits, '_', '-' and '.' only")
    if name is not None:
        _check_run_name(ctx, "with_values(name)", name)
    changed = replace(scenario, instances=tuple(instances), name=name or scenario.name)
    try:
        return _part_hold(changed) if scenario.part is not None and grouped else changed
    except KeyError as exc:
        ctx.fail("with_values", f"a mode of the tool is switched on without its {exc.args[0]}: give it too (the "
                                f"part's variable step holds the fine step until the modes ring down)")


def _part_hold(scenario: Scenario) -> Scenario:
    """A whole part's scenario with its ``[stepping].hold`` the ring-down of its tool's modes as they are now
    (values changed after the expansion), unless ``[part.stepping].hold`` fixed it."""
    from milling_twin.orchestrator.part.expand import ring_down_hold  # part.expand imports this module
    from milling_twin.orchestrator.part.model import VIBRATION

    st, part = scenario.stepping, scenario.part
    if st is None or part is None or part.hold is not None or VIBRATION not in scenario.execution_order:
        return scenario
    changes = [{str(ref): value for ref, value in entry.values} for entry in scenario.on_change]
    hold = ring_down_hold(scenario.instance(VIBRATION).parameters, changes, st.coarse_step)
    return replace(scenario, stepping=replace(st, hold_intervals=hold_intervals(hold, st.coarse_step)))
