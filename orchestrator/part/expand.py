"""A whole-part scenario (``[part]``) expanded into the explicit scenario: the five instances, their parameters,
the connections, ``[stepping]`` and the default record list, as the document :func:`load_scenario` reads.

:func:`expand_document` is what ``load_scenario`` calls on a file with ``[part]``; :func:`explicit_scenario` is
the expansion itself (a :class:`Part` and the FMUs' variables to a dict); ``milling-twin expand PART.toml
[-o FILE]`` (:func:`command`) writes the explicit scenario as TOML, paths relative to the written file.
What it expands to is described in ``docs/part.md``.
"""
from __future__ import annotations

import argparse
import copy
import os
import sys
from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import tomli_w

from milling_twin.models.stability import Mode, ring_down_time
from milling_twin.orchestrator.gcode.program_summary import summarize
from milling_twin.orchestrator.part.model import (FORCE, INTERPOLATOR, POWER, VIBRATION, WORKPIECE, CutTool,
                                                   Part)
from milling_twin.orchestrator.part.spec import read_part
from milling_twin.orchestrator.scenario import (ScenarioError, Variable, _Ctx, _load_fmu, _parameters, _variables,
                                                on_change_toml)
from milling_twin.orchestrator.toml_access import TomlAccess

INSTANCES = (INTERPOLATOR, WORKPIECE, FORCE, VIBRATION, POWER)
# Tables that may stand beside [part] (kept as they are; [fmus.<instance>] overrides single parameters; [optimize]
# is read by `milling-twin optimize` only, orchestrator/optimize/spec.py)
BESIDE_PART = ("scenario", "part", "fmus", "recorded", "inputs", "outputs", "compare", "alignment", "optimize")
DEFAULT_OUTPUT_INTERVAL = 1e-4      # s
STOP_MARGIN = 0.05                  # s after the program's machining time
CLEARANCE_MARGIN = 1.5              # the Workpiece looks for material this many lookaheads around the tool
CLEARANCE_RANGE = 3e-3              # m: how far it looks without a lookahead (the recorded clearance)
# The tool's vibration left, relative to its amplitude on leaving material, when force and vibration go back to
# the coarse step: then a cut entered again soon after sees a regenerative chip and a vibration that differ from
# the all-fine run's by this much of it at most (the free response itself is exact at any step)
RING_DOWN = 1e-6
RECORD = {
    INTERPOLATOR: ("x", "y", "z", "x_program", "y_program", "z_program", "feed", "spindle_speed", "line_number",
                   "tool_number"),
    WORKPIECE: ("axial_depth", "radial_depth", "entry_angle", "exit_angle", "mrr", "removed_volume", "clearance"),
    FORCE: ("Fx", "Fy", "Fz", "torque", "power"),
    VIBRATION: ("tip_displacement_x", "tip_displacement_y"),
    POWER: ("P_total", "P_cutting"),
}
MODELS = {INTERPOLATOR: "Interpolator", WORKPIECE: "Workpiece", VIBRATION: "ToolVibration", POWER: "SpindlePower"}


def models_of(part_table: Any) -> dict[str, str]:
    """The FMU (model name) of each instance; the force model from ``[part].force_model``."""
    force = part_table.get("force_model", "CuttingForce") if isinstance(part_table, dict) else "CuttingForce"
    return {**MODELS, FORCE: force if force in ("CuttingForce", "ForceNet") else "CuttingForce"}


def fmu_variables(ctx: TomlAccess, models: Mapping[str, str], fmu_dir: Path) -> dict[str, dict[str, Variable]]:
    """The variables of each instance's FMU (FMI 3, in ``fmu_dir``), by instance name."""
    out = {}
    for inst, model in models.items():
        try:
            _, _, md = _load_fmu(ctx, inst, {"fmu": model}, fmu_dir)
        except ScenarioError as exc:
            ctx.fail("[part]", f"the part's instance {inst!r}: {exc.detail}")
        out[inst] = _variables(md)
    return out


def expand_document(ctx: TomlAccess, doc: dict[str, Any], fmu_dir: Path) -> tuple[dict[str, Any], Part]:
    """The explicit scenario document of a file with ``[part]`` (paths absolute), and its Part."""
    ctx.table(doc, "", BESIDE_PART)
    variables = fmu_variables(ctx, models_of(doc["part"]), fmu_dir)
    part = read_part(ctx, doc["part"], {"Interpolator": variables[INTERPOLATOR], "SpindlePower": variables[POWER]})
    if part.cutting_power == "force" and "cutting_power" not in variables[POWER]:
        ctx.fail("[part].cutting_power", f"\"force\" needs SpindlePower's input cutting_power, which the FMU in "
                                         f"{fmu_dir} does not have (built before it was added): rebuild the FMUs, "
                                         f"or use cutting_power = \"mrr\"")
    if len(part.cutting_tools) > 1 and "tool_length" not in variables[WORKPIECE]:
        ctx.fail("[part].program", f"the program cuts with {len(part.cutting_tools)} tools, and the Workpiece FMU in "
                                   f"{fmu_dir} has no tool_length (built before tool changes): rebuild the FMUs")
    scenario = dict(ctx.table(doc.get("scenario"), "[scenario]", (
        "name", "description", "start_time", "stop_time", "output_interval", "parameter_sets")))
    scenario.setdefault("output_interval", DEFAULT_OUTPUT_INTERVAL)
    if "stop_time" not in scenario and "recorded" not in doc:
        try:
            summary = summarize(part.program, part.dialect, part.tools, part.machine)
        except ValueError as exc:  # the path or the schedule refuses the program (the FMU would too)
            ctx.fail("[part].program", str(exc))
        part = replace(part, machining_time=summary.time)
        scenario["stop_time"] = round(summary.time + STOP_MARGIN, 9)
    explicit = explicit_scenario(part, variables, scenario, doc)
    for inst, table in explicit["fmus"].items():  # a value out of an FMU's range, named by the part's key
        for section, causality in (("parameters", "parameter"), ("inputs", "input")):
            try:
                _parameters(ctx, inst, table.get(section, {}), variables[inst], table["fmu"], causality)
            except ScenarioError as exc:
                name = exc.key.rpartition(".")[2]
                ctx.fail(_origin(inst, name), f"{exc.detail} (as {exc.key} of the expanded scenario)")
    _overrides(ctx, explicit, doc.get("fmus", {}))
    if part.hold is None and doc.get("fmus", {}).get(VIBRATION):  # the modes as overridden ring down in their time
        vibration = _parameters(ctx, VIBRATION, explicit["fmus"][VIBRATION]["parameters"], variables[VIBRATION],
                                "ToolVibration")
        try:
            explicit["stepping"]["hold"] = _hold(explicit, vibration, part.coarse_step)
        except KeyError as exc:
            ctx.fail(f"[fmus.{VIBRATION}].parameters", f"a mode is switched on without its {exc.args[0]}: give it, "
                                                      f"or [part.stepping].hold (the hold is the modes' ring-down)")
    return explicit, part


def _origin(instance: str, name: str) -> str:
    """The key of ``[part]`` an expanded parameter (or input) comes from."""
    if instance == INTERPOLATOR:
        return {"period": "[part.stepping].coarse_step", "feed_override": "[part].feed_override"}.get(
            name, f"[part.machine].{name}")
    if instance == WORKPIECE:
        if name.startswith("stock_") or name == "resolution":
            return "[part.stock]"
        return {"flute_length": "[part].flute_length", "clearance_range": "[part.stepping].lookahead",
                "max_tool_speed": "[part.machine]"}.get(name, "[part].tool_table")
    if instance == FORCE:
        return "[part].tool_table" if name in ("n_flutes", "tool_diameter", "helix_angle") else "[part].material"
    if instance == VIBRATION:
        return "[part.tool_modes]"
    return "[part].cutting_power" if name == "cutting_power_from_force" else f"[part.spindle].{name}"


def explicit_scenario(part: Part, variables: Mapping[str, Mapping[str, Variable]], scenario: Mapping[str, Any],
                      beside: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The explicit scenario of ``part``: ``variables`` the FMU variables by instance (the expansion uses an
    optional variable only where the FMU has it: the Workpiece's clearance, SpindlePower's cutting_power),
    ``scenario`` the ``[scenario]`` table, ``beside`` the tables standing beside ``[part]`` (kept)."""
    beside = beside or {}
    tool = part.tool
    has = {inst: set(v) for inst, v in variables.items()}
    fed_inputs = {item.get("to") for item in beside.get("inputs", []) if isinstance(item, dict)}
    interp: dict[str, Any] = {
        "program": {"path": str(part.program)}, "dialect": part.dialect,
        **({"tool_table": {"path": str(part.tool_table)}} if part.tool_table else {}), **part.machine}
    # the Workpiece follows the machine position: the stock (program coordinates) at the program zero of the cut
    x0, y0, z0 = (o + zero for o, zero in zip(part.stock.origin, part.program_zero))
    cutting = part.cutting_tools
    several = len(cutting) > 1
    workpiece: dict[str, Any] = {
        "stock_x_min": x0, "stock_y_min": y0, "stock_z_min": z0,
        "stock_length": part.stock.size[0], "stock_width": part.stock.size[1], "stock_height": part.stock.size[2],
        "resolution": part.stock.resolution, **_workpiece_tool(cutting[0], several),
        "flute_count": tool.flutes, "helix_angle": tool.helix}
    if "clearance_range" in has[WORKPIECE]:
        workpiece["clearance_range"] = CLEARANCE_MARGIN * part.lookahead if part.lookahead > 0 else CLEARANCE_RANGE
    fastest = max(part.machine.get("rapid_feed", 0.0), part.machine.get("max_feed", 0.0))
    if fastest * 1.5 > 2.0:  # the Workpiece's default max_tool_speed (2 m/s) refuses faster jumps
        workpiece["max_tool_speed"] = 1.5 * fastest
    force: dict[str, Any] = force_tool_parameters(cutting[0])
    if part.force_model == "CuttingForce":
        force.update(part.material.coefficients)
    vibration = vibration_parameters(cutting[0])
    power: dict[str, Any] = dict(part.spindle)
    from_force = part.cutting_power == "force"
    if "cutting_power_from_force" in has[POWER]:
        power["cutting_power_from_force"] = from_force

    fmus = {
        INTERPOLATOR: _instance("Interpolator", part.coarse_step, interp,
                                {} if f"{INTERPOLATOR}.feed_override" in fed_inputs
                                else {"feed_override": part.feed_override}),
        WORKPIECE: _instance("Workpiece", part.coarse_step, workpiece),
        FORCE: _instance(part.force_model, part.fine_step, force),
        VIBRATION: _instance("ToolVibration", part.fine_step, vibration),
        POWER: _instance("SpindlePower", part.coarse_step, power),
    }
    links = [(f"{INTERPOLATOR}.{a}", f"{WORKPIECE}.{b}") for a, b in (
        ("x", "tool_x"), ("y", "tool_y"), ("z", "tool_z"), ("spindle_speed", "spindle_speed"))]
    links += [(f"{INTERPOLATOR}.{v}", f"{FORCE}.{v}") for v in ("spindle_speed", "feed_velocity_x", "feed_velocity_y")]
    links += [(f"{WORKPIECE}.{v}", f"{FORCE}.{v}") for v in ("axial_depth", "entry_angle", "exit_angle")]
    if part.force_model == "ForceNet":
        links.append((f"{WORKPIECE}.engagement", f"{FORCE}.engagement"))  # the whole 8 x 24 map
    links += [(f"{FORCE}.Fx", f"{VIBRATION}.force_x"), (f"{FORCE}.Fy", f"{VIBRATION}.force_y")]
    links += [(f"{INTERPOLATOR}.{v}", f"{POWER}.{v}") for v in ("spindle_on", "spindle_speed")]
    if "spindle_speed_command" in has[POWER]:
        links.append((f"{INTERPOLATOR}.spindle_speed", f"{POWER}.spindle_speed_command"))
    links.append((f"{WORKPIECE}.mrr", f"{POWER}.mrr"))
    if from_force and "cutting_power" in has[POWER]:
        links.append((f"{FORCE}.power", f"{POWER}.cutting_power"))
    connections = [{"from": a, "to": b} for a, b in links]
    connections += [{"from": f"{VIBRATION}.tip_displacement_{axis}", "to": f"{FORCE}.displacement_{axis}",
                     "delay": True} for axis in "xy"]  # the tool's vibration comes back one fine step late

    fine_when: list[dict[str, Any]] = [{"output": f"{WORKPIECE}.axial_depth", "above": 0.0}]
    if part.lookahead > 0 and "clearance" in has[WORKPIECE]:
        fine_when.append({"output": f"{WORKPIECE}.clearance", "below": part.lookahead})
    doc: dict[str, Any] = {"scenario": dict(scenario), "fmus": fmus, "connections": connections,
                           "stepping": {"coarse_step": part.coarse_step, "variable": [FORCE, VIBRATION],
                                        "fine_when": fine_when}}
    if several:  # the tool change: the next tool's geometry and modes from the communication point it shows
        doc["on_change"] = [{"output": f"{INTERPOLATOR}.tool_number", "equals": c.tool.number, "set": {
            **{f"{WORKPIECE}.{k}": v for k, v in _workpiece_tool(c, True).items()},
            **{f"{FORCE}.{k}": v for k, v in force_tool_parameters(c).items()},
            **{f"{VIBRATION}.{k}": v for k, v in vibration_parameters(c).items()}}} for c in cutting]
    doc["stepping"]["hold"] = part.hold if part.hold is not None else _hold(doc, vibration, part.coarse_step)
    for name in ("recorded", "inputs", "compare", "alignment"):
        if name in beside:
            doc[name] = copy.deepcopy(beside[name])
    doc["outputs"] = copy.deepcopy(beside["outputs"]) if "outputs" in beside else {"record": [
        f"{inst}.{v}" for inst, names in RECORD.items() for v in names if v in has[inst]]}
    return doc


def _workpiece_tool(c: CutTool, with_length: bool) -> dict[str, Any]:
    """The Workpiece's parameters of one tool (tool_length only where the part has several: older FMUs lack it)."""
    values = {"tool_diameter": c.tool.diameter, "corner_radius": c.tool.corner_radius, "flute_length": c.flute_length}
    return {**values, "tool_length": c.length} if with_length else values


def force_tool_parameters(c: CutTool) -> dict[str, Any]:
    """The force model's parameters of one tool (its geometry; the material's coefficients are the part's)."""
    return {"n_flutes": c.tool.flutes, "tool_diameter": c.tool.diameter, "helix_angle": c.tool.helix}


def _hold(doc: Mapping[str, Any], vibration: Mapping[str, Any], coarse_step: float) -> float:
    """``[stepping].hold`` (s) of the explicit scenario ``doc`` (its tool changes in ``doc["on_change"]``)."""
    return ring_down_hold(vibration, [entry["set"] for entry in doc.get("on_change", ())], coarse_step)


def ring_down_hold(vibration: Mapping[str, Any], changes: Sequence[Mapping[str, Any]], coarse_step: float) -> float:
    """``[stepping].hold`` (s): the time in which the slowest mode of any tool rings down to RING_DOWN of its
    amplitude (``vibration``: ToolVibration's parameters, SI; ``changes``: each tool change's values, keyed
    ``"vibration.<name>"``), at least one coarse step. A KeyError names a mode's value that neither gives."""
    prefix = f"{VIBRATION}."
    sets = [dict(vibration)] + [{**vibration, **{k[len(prefix):]: v for k, v in change.items()
                                                  if k.startswith(prefix)}} for change in changes]
    modes = [Mode(float(p[f"frequency_{axis}{i}"]), float(p[f"damping_{axis}{i}"]), float(p[f"stiffness_{axis}{i}"]))
             for p in sets for axis in "xy" for i in range(1, int(p.get(f"n_modes_{axis}", 0)) + 1)]
    return max(coarse_step, ring_down_time(modes, RING_DOWN))


def vibration_parameters(c: CutTool) -> dict[str, Any]:
    """ToolVibration's modes of one tool; with tool changes the unused modes of a direction are switched off by
    n_modes (their values stay those of the tool that had them)."""
    vibration: dict[str, Any] = {"n_modes_x": len(c.modes_x), "n_modes_y": len(c.modes_y)}
    for axis, modes in (("x", c.modes_x), ("y", c.modes_y)):
        for i, mode in enumerate(modes, start=1):
            vibration.update({f"frequency_{axis}{i}": mode.frequency, f"damping_{axis}{i}": mode.damping,
                              f"stiffness_{axis}{i}": mode.stiffness})
    return vibration


def _instance(model: str, step: float, parameters: dict[str, Any], inputs: dict[str, Any] | None = None) -> dict:
    table: dict[str, Any] = {"fmu": model, "step_size": step, "parameters": parameters}
    if inputs:
        table["inputs"] = inputs
    return table


def _overrides(ctx: TomlAccess, explicit: dict[str, Any], fmus: Any) -> None:
    """``[fmus.<instance>]`` beside ``[part]``: single parameters (and constant inputs) of the expanded instances."""
    if not isinstance(fmus, dict):
        ctx.fail("[fmus]", f"expected a table of [fmus.<instance>] overrides, got {fmus!r}")
    for inst, table in fmus.items():
        key = f"[fmus.{inst}]"
        if inst not in explicit["fmus"]:
            ctx.fail(key, f"beside [part], [fmus] only overrides parameters of the part's instances "
                          f"{', '.join(INSTANCES)}; {inst!r} is not one of them")
        ctx.table(table, key, ("parameters", "inputs"))
        for section in ("parameters", "inputs"):
            values = table.get(section, {})
            if not isinstance(values, dict):
                ctx.fail(f"{key}.{section}", f"expected a table, got {values!r}")
            if values:
                target = explicit["fmus"][inst].setdefault(section, {})
                target.update({name: _absolute(ctx, value) for name, value in values.items()})


def _absolute(ctx: TomlAccess, value: Any) -> Any:
    """A ``{ path = ... }`` of an override, relative to the part file, made absolute."""
    if isinstance(value, dict) and set(value) == {"path"} and isinstance(value["path"], str):
        return {"path": str((ctx.path.parent / value["path"]).resolve())}
    return value


def relocate(doc: dict[str, Any], source: Path, target: Path) -> dict[str, Any]:
    """``doc`` (paths absolute or relative to ``source``, a folder) with every path relative to ``target``."""
    def moved(text: str) -> str:
        return Path(os.path.relpath((source / text).resolve(), target.resolve())).as_posix()

    out = copy.deepcopy(doc)
    for inst in out.get("fmus", {}).values():
        for values in (inst.get("parameters", {}), inst.get("inputs", {})):
            for name, value in values.items():
                if isinstance(value, dict) and set(value) == {"path"}:
                    values[name] = {"path": moved(value["path"])}
    if "recorded" in out and isinstance(out["recorded"].get("file"), str):
        out["recorded"]["file"] = moved(out["recorded"]["file"])
    sets = out["scenario"].get("parameter_sets")
    if isinstance(sets, list):
        out["scenario"]["parameter_sets"] = [moved(s) if isinstance(s, str) else s for s in sets]
    return out


def explicit_text(part_file: Path, fmu_dir: Path, target_dir: Path) -> tuple[str, Part]:
    """The explicit scenario of ``part_file`` as TOML, paths relative to ``target_dir``, and its Part."""
    ctx = _Ctx(part_file)
    _, doc = ctx.document("scenario")
    if "part" not in doc:
        ctx.fail("[part]", "missing required table: this is not a whole-part scenario (see docs/part.md)")
    explicit, part = expand_document(ctx, doc, fmu_dir)
    header = (f"# The explicit scenario of {part_file.name} (its [part] expanded by `milling-twin expand`): the same "
              f"run as the part file.\n# Values in SI units; paths relative to this file.\n")
    warnings = "".join(f"# check: {w}\n" for w in part.warnings)
    return header + warnings + "\n" + scenario_toml(relocate(explicit, part_file.parent, target_dir)), part


def scenario_toml(doc: Mapping[str, Any]) -> str:
    """``doc`` as TOML in reading order ([scenario] first), arrays of tables as ``[[name]]`` blocks."""
    order = ("scenario", "fmus", "connections", "stepping", "on_change", "recorded", "alignment", "inputs", "compare",
             "outputs")
    chunks = []
    for name in sorted(doc, key=lambda n: order.index(n) if n in order else len(order)):
        value = doc[name]
        if name == "on_change":  # its set = { ... } inline, as written (orchestrator.scenario.on_change_toml)
            chunks.append(on_change_toml(value))
        elif isinstance(value, list) and all(isinstance(item, dict) for item in value):
            chunks.extend(f"[[{name}]]\n{tomli_w.dumps(item)}" for item in value)
        elif name == "fmus":
            chunks.extend(_instance_toml(inst, table) for inst, table in value.items())
        else:
            chunks.append(tomli_w.dumps({name: value}))
    return "\n".join(chunks)


def _instance_toml(name: str, table: Mapping[str, Any]) -> str:
    """``[fmus.<name>]`` with its parameters and inputs one per line (a file as ``{ path = "..." }``)."""
    def line(key: str, value: Any) -> str:
        if isinstance(value, dict):
            return f"{key} = {{ {', '.join(tomli_w.dumps({k: v}).strip() for k, v in value.items())} }}\n"
        return tomli_w.dumps({key: value})

    text = f"[fmus.{name}]\n" + "".join(line(k, v) for k, v in table.items() if not isinstance(v, dict))
    for section in ("parameters", "inputs"):
        if section in table:
            text += f"[fmus.{name}.{section}]\n" + "".join(line(k, v) for k, v in table[section].items())
    return text


def command(args: argparse.Namespace) -> int:
    """``milling-twin expand PART.toml [-o FILE] [--fmu-dir DIR]``: without -o, to stdout (paths relative to the
    current directory)."""
    target = args.output.parent if args.output else Path.cwd()
    text, part = explicit_text(args.part, args.fmu_dir, target)
    if args.output:
        args.output.parent.mkdir(parents=True, exist_ok=True)
        args.output.write_text(text, encoding="utf-8")
        print(f"{args.output}: {', '.join(INSTANCES)} ({part.force_model}; T{part.tool.number}, "
              f"D {part.tool.diameter * 1000:g} mm)")
    else:
        sys.stdout.write(text)
    return 0
