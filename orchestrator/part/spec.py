"""``[part]`` of a scenario file read into a :class:`Part` (SI values, absolute paths) and checked.

Every value is a number in SI units or ``{ value = ..., unit = "..." }`` (``models/units.py``), like the rest of
a scenario; every mistake is a :class:`ScenarioError` naming the scenario file and the key. The format is in
``docs/part.md``. The program is parsed here as the Interpolator parses it (to find the tools it cuts with)
and checked against the stock and the tool (``orchestrator/part/checks.py``) before anything runs.
"""
from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any, NoReturn

from milling_twin.models.interpolator.definition import default_parameters
from milling_twin.models.interpolator.parser import DIALECTS, ProgramError, Tool
from milling_twin.models.interpolator.tool_table import read_tool_table
from milling_twin.models.materials import COEFFICIENTS, MATERIALS
from milling_twin.models.stability import Mode
from milling_twin.models.units import UnitError, conversion_factor
from milling_twin.orchestrator.gcode.recognise import NotThatFileError, check_part_program, check_tool_table
from milling_twin.orchestrator.part import checks
from milling_twin.orchestrator.part.model import CutTool, Material, Part, Stock
from milling_twin.orchestrator.scenario import Variable, _parameters
from milling_twin.orchestrator.toml_access import TomlAccess

PART_KEYS = ("program", "dialect", "tool_table", "force_model", "cutting_power", "material", "feed_override",
             "flute_length", "stock", "machine", "spindle", "tool_modes", "stepping")
FORCE_MODELS = ("CuttingForce", "ForceNet")
CUTTING_POWER = ("force", "mrr")
MAX_MODES = 4                       # ToolVibration: up to 4 modes per direction
DEFAULT_FINE_STEP = 1e-5            # s
FORCENET_MATERIAL = "Al7075-T6"     # ForceNet learned the mechanistic model with these coefficients
_log = logging.getLogger("milling_twin.part")
# Set by [part] itself, not by [part.machine] / [part.spindle]
_MACHINE_OWN = {"program": "[part].program", "dialect": "[part].dialect", "tool_table": "[part].tool_table"}
_SPINDLE_OWN = {"cutting_power_from_force": "[part].cutting_power"}


def quantity(ctx: TomlAccess, table: Mapping, key: str, name: str, unit: str, default: Any = ...,
             positive: bool = False) -> Any:
    """``table[name]``: a number in ``unit`` (SI) or ``{ value, unit }``, in ``unit``; ``default`` when absent."""
    k = f"{key}.{name}"
    if name not in table:
        if default is ...:
            ctx.fail(k, "missing required key")
        return default
    raw, given = _value_unit(ctx, k, table[name])
    if isinstance(raw, bool) or not isinstance(raw, (int, float)) or not math.isfinite(raw):
        ctx.fail(k, f"expected a finite number or {{ value, unit }}, got {table[name]!r}")
    value = float(raw) * _factor(ctx, k, given, unit)
    if positive and value <= 0.0:
        ctx.fail(k, f"must be > 0, got {raw!r}")
    return value


def vector(ctx: TomlAccess, table: Mapping, key: str, name: str, unit: str,
           positive: bool = False) -> tuple[float, float, float]:
    """``table[name]``: three numbers in ``unit`` or ``{ value = [x, y, z], unit }``."""
    k = f"{key}.{name}"
    if name not in table:
        ctx.fail(k, "missing required key")
    raw, given = _value_unit(ctx, k, table[name])
    if not isinstance(raw, list) or len(raw) != 3 or not all(
            isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in raw):
        ctx.fail(k, f"expected three finite numbers [x, y, z] (or {{ value = [x, y, z], unit }}), got {table[name]!r}")
    factor = _factor(ctx, k, given, unit)
    values = tuple(float(x) * factor for x in raw)
    if positive and min(values) <= 0.0:
        ctx.fail(k, f"every value must be > 0, got {raw!r}")
    return values  # type: ignore[return-value]


def _value_unit(ctx: TomlAccess, key: str, raw: Any) -> tuple[Any, str | None]:
    if isinstance(raw, dict):
        ctx.table(raw, key, ("value", "unit"))
        if "value" not in raw:
            ctx.fail(f"{key}.value", "missing required key")
        return raw["value"], ctx.string(raw, key, "unit")
    return raw, None


def _factor(ctx: TomlAccess, key: str, given: str | None, unit: str) -> float:
    if given is None or given == unit:
        return 1.0
    try:
        return conversion_factor(given, unit)
    except UnitError as exc:
        ctx.fail(key, f"unit {given!r} does not fit (expected a unit convertible to {unit!r}): {exc}")


def _file(ctx: TomlAccess, table: Mapping, name: str) -> Path:
    resolved = (ctx.path.parent / ctx.string(table, "[part]", name)).resolve()
    if not resolved.exists():
        ctx.fail(f"[part].{name}", f"no file {resolved}")
    try:  # a regular file that looks like a program (tool table): a parser's message quotes only such a file
        (check_part_program if name == "program" else check_tool_table)(resolved)
    except NotThatFileError as exc:
        ctx.fail(f"[part].{name}", str(exc))
    return resolved


def _material(ctx: TomlAccess, raw: Any) -> Material:
    key = "[part].material"
    if isinstance(raw, str):
        if raw not in MATERIALS:
            ctx.fail(key, f"unknown material {raw!r}; presets (models/materials.py): {', '.join(MATERIALS)}, or "
                          f"a table of the coefficients {', '.join(COEFFICIENTS)}")
        preset = MATERIALS[raw]
        return Material(preset.name, dict(preset.coefficients), preset.source)
    table = ctx.table(raw, key, (*COEFFICIENTS, "name", "source"))
    coefficients = {name: quantity(ctx, table, key, name, "N/m2" if name.endswith("c") else "N/m")
                    for name in COEFFICIENTS}
    return Material(ctx.string(table, key, "name", "custom"), coefficients, ctx.string(table, key, "source", ""))


def _modes(ctx: TomlAccess, table: Mapping, axis: str, key: str = "[part.tool_modes]") -> tuple[Mode, ...]:
    key = f"{key}.{axis}"
    items = table.get(axis)
    if not isinstance(items, list) or len(items) > MAX_MODES:
        ctx.fail(key, f"expected a list of at most {MAX_MODES} modes "
                      f"[{{ frequency, damping, stiffness }}, ...], got {items!r}")
    modes = []
    for i, item in enumerate(items):
        k = f"{key}[{i}]"
        ctx.table(item, k, ("frequency", "damping", "stiffness"))
        modes.append(Mode(quantity(ctx, item, k, "frequency", "Hz", positive=True),
                          quantity(ctx, item, k, "damping", "1", positive=True),
                          quantity(ctx, item, k, "stiffness", "N/m", positive=True)))
    return tuple(modes)


def _named(ctx: TomlAccess, table: Any, key: str, variables: Mapping[str, Variable], model: str,
           own: Mapping[str, str]) -> dict[str, Any]:
    """Parameters of ``model`` by name (``[part.machine]``, ``[part.spindle]``), SI; ``own``: names [part] sets."""
    table = {} if table is None else table
    if not isinstance(table, dict):
        ctx.fail(key, f"expected a table, got {table!r}")
    for name in table:
        if name in own:
            ctx.fail(f"{key}.{name}", f"set by {own[name]}, not here")
    return _parameters(ctx, model, table, variables, model, key=key)


def read_part(ctx: TomlAccess, raw: Any, variables: Mapping[str, Mapping[str, Variable]]) -> Part:
    """``[part]`` as a :class:`Part`, checked (program, tool table, stock, tool); ``variables``: the variables of
    the FMUs by model name (Interpolator and SpindlePower: ``[part.machine]``, ``[part.spindle]``)."""
    table = ctx.table(raw, "[part]", PART_KEYS)
    program = _file(ctx, table, "program")
    dialect = ctx.string(table, "[part]", "dialect", "fanuc", choices=tuple(DIALECTS))
    tool_table = _file(ctx, table, "tool_table")
    try:
        tools = read_tool_table(tool_table)
    except ProgramError as exc:
        ctx.fail("[part].tool_table", str(exc))
    force_model = ctx.string(table, "[part]", "force_model", "CuttingForce", choices=FORCE_MODELS)
    cutting_power = ctx.string(table, "[part]", "cutting_power", "force", choices=CUTTING_POWER)
    if "material" not in table:
        ctx.fail("[part].material", f"missing required key (a preset: {', '.join(MATERIALS)}; or a table of "
                                    f"{', '.join(COEFFICIENTS)})")
    material = _material(ctx, table["material"])
    feed_override = ctx.number(table, "[part]", "feed_override", 1.0, minimum=0.0)

    stock_table = ctx.table(table.get("stock"), "[part.stock]", ("origin", "size", "resolution"))
    stock = Stock(vector(ctx, stock_table, "[part.stock]", "origin", "m"),
                  vector(ctx, stock_table, "[part.stock]", "size", "m", positive=True),
                  quantity(ctx, stock_table, "[part.stock]", "resolution", "m", positive=True))
    if stock.resolution > min(stock.size[:2]):
        ctx.fail("[part.stock].resolution", f"{stock.resolution!r} m is larger than the stock's length or width")

    machine = _named(ctx, table.get("machine"), "[part.machine]", variables["Interpolator"], "Interpolator",
                     _MACHINE_OWN)
    spindle = _named(ctx, table.get("spindle"), "[part.spindle]", variables["SpindlePower"], "SpindlePower",
                     _SPINDLE_OWN)

    modes_table = ctx.table(table.get("tool_modes"), "[part.tool_modes]",
                            ("x", "y", *(f"T{t.number}" for t in tools)))

    step_table = ctx.table(table.get("stepping", {}), "[part.stepping]",
                           ("fine_step", "coarse_step", "lookahead", "hold"))
    period = float(machine.get("period", default_parameters()["period"]))
    coarse = quantity(ctx, step_table, "[part.stepping]", "coarse_step", "s", period, positive=True)
    if "period" in machine and abs(coarse - period) > 1e-12:
        ctx.fail("[part.stepping].coarse_step", f"{coarse!r} s differs from the machine's period {period!r} s "
                                                f"([part.machine].period): the Interpolator steps at its period")
    machine["period"] = coarse
    fine = quantity(ctx, step_table, "[part.stepping]", "fine_step", "s", DEFAULT_FINE_STEP, positive=True)
    if fine > coarse:
        ctx.fail("[part.stepping].fine_step", f"{fine!r} s is longer than coarse_step {coarse!r} s")
    if abs(coarse / fine - round(coarse / fine)) > 1e-6 * coarse / fine:
        ctx.fail("[part.stepping].fine_step", f"{fine!r} s does not divide coarse_step {coarse!r} s a whole number "
                                              f"of times")
    lookahead = quantity(ctx, step_table, "[part.stepping]", "lookahead", "m", 0.0, positive="lookahead" in step_table)
    hold = quantity(ctx, step_table, "[part.stepping]", "hold", "s", None)
    if hold is not None and hold < coarse * (1.0 - 1e-9):
        ctx.fail("[part.stepping].hold", f"{hold!r} s is shorter than coarse_step {coarse!r} s: the interval in "
                                         f"which the tool leaves material must be stepped finely")

    try:
        parsed = checks.parse(program, dialect, tools, machine)
    except ValueError as exc:  # ProgramError: file, line, text, what was expected (an unknown T among them)
        ctx.fail("[part].program", str(exc))
    path = checks.feed_path(parsed)

    def fail(message: str) -> NoReturn:
        ctx.fail("[part].program", message)

    cutting = checks.cutting_tools(path, tools, stock, fail)
    if force_model == "ForceNet" and len(cutting) > 1:
        ctx.fail("[part].force_model", f"\"ForceNet\" learned the forces of one tool; the program cuts with "
                                       f"{len(cutting)} tools ({', '.join(f'T{t.number}' for t in cutting)}): use "
                                       f"\"CuttingForce\", or one part per tool")
    zeros = checks.cutting_offsets(path, tools, cutting, stock, fail)
    base = min(z[2] for z in zeros)  # the lowest zero: every tool's length above it is >= 0
    cut_tools = []
    for tool, zero in zip(cutting, zeros):
        _tool_geometry(ctx, tool, tool_table)
        flute_length = quantity(ctx, table, "[part]", "flute_length", "m", tool.stick_out)
        if flute_length <= 0.0:
            ctx.fail("[part].flute_length", f"T{tool.number} of {tool_table} gives no stick_out= (the flute length "
                                            f"of the Workpiece and the depth check): add stick_out=<mm> to its "
                                            f"comment or set [part].flute_length")
        modes_x, modes_y = _tool_modes(ctx, modes_table, tool)
        cut_tools.append(CutTool(tool, modes_x, modes_y, flute_length, zero[2] - base))
    warnings = checks.check_part(path, tools, [(c.tool, c.flute_length) for c in cut_tools], stock, fail)
    first = cut_tools[0]
    if force_model == "ForceNet" and material.name != FORCENET_MATERIAL:
        warnings.append(f"[part].material: ForceNet learned the forces of {FORCENET_MATERIAL}; the material "
                        f"{material.name!r} is not used by it (use force_model = \"CuttingForce\")")
        _log.warning("%s", warnings[-1])
    return Part(program=program, dialect=dialect, tool_table=tool_table, tool=first.tool, stock=stock,
                material=material, modes_x=first.modes_x, modes_y=first.modes_y, force_model=force_model,
                cutting_power=cutting_power, fine_step=fine, coarse_step=coarse, lookahead=lookahead, hold=hold,
                machine=machine,
                spindle=spindle, feed_override=feed_override, flute_length=first.flute_length,
                program_zero=(zeros[0][0], zeros[0][1], base), warnings=tuple(warnings), tools=tuple(tools),
                tool_length=first.length, later_tools=tuple(cut_tools[1:]))


def _tool_modes(ctx: TomlAccess, table: Mapping, tool: Tool) -> tuple[tuple[Mode, ...], tuple[Mode, ...]]:
    """The tip modes of ``tool``: ``[part.tool_modes].T<n>`` (x and y) when given, else ``x`` and ``y``."""
    own = f"T{tool.number}"
    if own in table:
        key = f"[part.tool_modes.{own}]"
        modes = ctx.table(table[own], key, ("x", "y"))
        return _modes(ctx, modes, "x", key), _modes(ctx, modes, "y", key)
    if "x" not in table and "y" not in table:
        ctx.fail("[part.tool_modes]", f"no modes for T{tool.number}, which cuts the part: give x and y (every tool's "
                                      f"modes), or {own} = {{ x = [...], y = [...] }}")
    return _modes(ctx, table, "x"), _modes(ctx, table, "y")


def _tool_geometry(ctx: TomlAccess, tool: Tool, tool_table: Path) -> None:
    """The tool the part cuts with needs a diameter and flutes (the Workpiece and the force model)."""
    if tool.diameter <= 0.0:
        ctx.fail("[part].tool_table", f"T{tool.number} of {tool_table} has no diameter D (> 0 mm)")
    if tool.flutes < 1:
        ctx.fail("[part].tool_table", f"T{tool.number} of {tool_table} gives no flutes= (the force model's "
                                      f"number of flutes): add flutes=<n> to its comment")
