"""The model definition ``INTERPOLATOR``: variables, units, ranges, defaults (the FMU's parameters and
outputs; ``fmus/interpolator/model.c`` reads them through the generated ``model_generated.h``)."""
from __future__ import annotations

import math

from milling_twin.models.definition import ModelDefinition, Variable
from milling_twin.models.interpolator import (cutter_comp, numbers, nurbs, param_update, parser, path, schedule,
                                             tool_table)
from milling_twin.models.interpolator.param_update import RBF_HIDDEN, RBF_INPUTS
from milling_twin.models.interpolator.parser import OFFSET_NAMES

# Default RBF network: trained by milling_twin/training/rbf.py on the butterfly curve of
# scenarios/nurbs/ (F 100 mm/s, A 1000 mm/s2, J 1e5 mm/s3, 1 um, 1 ms); rewritten by
# `milling-twin train rbf`.
# BEGIN RBF DEFAULTS
RBF_DEFAULTS: dict[str, float] = {
    "rbf_width": 1.5,
    "rbf_offset_1": 0.0, "rbf_offset_2": 0.0, "rbf_offset_3": 0.0, "rbf_offset_4": 0.0,
    "rbf_scale_1": 1.0, "rbf_scale_2": 1.0, "rbf_scale_3": 1.0, "rbf_scale_4": 1.0,
    **{f"rbf_center_{j}_{d}": 0.0 for j in range(1, 6) for d in range(1, 5)},
    **{f"rbf_weight_{j}": 0.0 for j in range(1, 6)},
    "rbf_bias": 0.0,
}
# END RBF DEFAULTS

JERK_UNIT = "m/s3"
# the default look-ahead window (blocks): more than any committed program holds, so those are planned whole
LOOKAHEAD_BLOCKS = 1000


def _variables() -> tuple[Variable, ...]:
    fixed = "fixed"
    v: list[Variable] = [
        Variable("program", "String", "parameter",
                 "Part program file (absolute path, or relative to the working directory); empty: "
                 "resources/program.nc of the FMU", start="", variability=fixed),
        Variable("dialect", "String", "parameter",
                 "G-code dialect of the part program: fanuc (also Haas and most post-processors' Fanuc posts), "
                 "linuxcnc or sinumerik (Siemens 840D); docs/interpolator.md lists the differences",
                 start="fanuc", variability=fixed),
        Variable("tool_table", "String", "parameter",
                 "Tool table file in LinuxCNC's format (T, D diameter mm, Z length mm; corner_radius, flutes, helix, "
                 "stick_out, name as key=value in the comment), absolute or relative to the working directory; "
                 "empty: no tool table (T words select tools without geometry)", start="", variability=fixed),
        Variable("period", "Float64", "parameter", "Interpolation period", unit="s", display_unit="ms",
                 start=1e-3, min=1e-5, max=0.1, variability=fixed),
        Variable("method", "Int32", "parameter",
                 "NURBS parameter update: 1 first-order Taylor, 2 second-order Taylor, 3 RBF network, "
                 "4 predictor-corrector (Newton on the arc length of the step)", start=4, min=1, max=4,
                 variability=fixed),
        Variable("corrector_predictor", "Int32", "parameter",
                 "Predictor refined by method 4: 1 first-order Taylor, 2 second-order Taylor, 3 RBF network",
                 start=2, min=1, max=3, variability=fixed),
        Variable("arc_length_feedback", "Boolean", "parameter",
                 "NURBS steps aim at the scheduled arc length from the actual position (the arcs travelled in "
                 "the block), so the error of an inexact update does not accumulate; false: the scheduled step as "
                 "is (open loop, as in the NURBS-interpolation literature; the block's last tenth lands on its end)",
                 start=True, variability=fixed),
        Variable("corrector_tolerance", "Float64", "parameter",
                 "Method 4: relative tolerance of the step's arc length (|arc - step| / step)",
                 start=1e-6, min=1e-15, max=1e-2, variability=fixed),
        Variable("max_feed", "Float64", "parameter", "Highest feed a program may command (F is clipped)",
                 unit="m/s", display_unit="mm/min", start=1.0 / 3.0, min=1e-6, max=10.0, variability=fixed),
        Variable("rapid_feed", "Float64", "parameter", "Path speed of rapid moves (G0; no override)",
                 unit="m/s", display_unit="mm/min", start=1.0 / 6.0, min=1e-6, max=10.0, variability=fixed),
        Variable("acceleration", "Float64", "parameter", "Tangential (path) acceleration limit",
                 unit="m/s2", display_unit="mm/s2", start=1.0, min=1e-3, max=1e3, variability=fixed),
        Variable("jerk", "Float64", "parameter",
                 "Tangential jerk limit, also the curvature jerk limit v^3 kappa^2",
                 unit=JERK_UNIT, display_unit="mm/s3", start=100.0, min=1e-2, max=1e6, variability=fixed),
        Variable("centripetal_acceleration", "Float64", "parameter", "Centripetal acceleration limit v^2 kappa",
                 unit="m/s2", display_unit="mm/s2", start=1.0, min=1e-3, max=1e3, variability=fixed),
        Variable("chord_error", "Float64", "parameter", "Largest distance between the path and the chord "
                 "between two interpolation points", unit="m", display_unit="um", start=1e-6, min=1e-9,
                 max=1e-3, variability=fixed),
    ]
    for axis in "xyz":
        v.append(Variable(f"axis_acceleration_{axis}", "Float64", "parameter",
                          f"Acceleration limit of the {axis.upper()} axis", unit="m/s2", display_unit="mm/s2",
                          start=2.0, min=1e-3, max=1e4, variability=fixed))
    for axis in "xyz":
        v.append(Variable(f"axis_jerk_{axis}", "Float64", "parameter",
                          f"Jerk limit of the {axis.upper()} axis", unit=JERK_UNIT, display_unit="mm/s3", start=300.0,
                          min=1e-2, max=1e7, variability=fixed))
    for axis in "xyz":
        v.append(Variable(f"start_{axis}", "Float64", "parameter",
                          f"Machine {axis.upper()} position of the tool before the program starts",
                          unit="m", display_unit="mm", start=0.0, min=-10.0, max=10.0, variability=fixed))
    for axis in "xyz":
        v.append(Variable(f"home_{axis}", "Float64", "parameter",
                          f"Machine {axis.upper()} position of the reference point that G28 returns to",
                          unit="m", display_unit="mm", start=0.0, min=-10.0, max=10.0, variability=fixed))
    for name in OFFSET_NAMES:
        for axis in "xyz":
            v.append(Variable(f"{name}_{axis}", "Float64", "parameter",
                              f"Work offset {name.upper()}: machine {axis.upper()} position of the work zero",
                              unit="m", display_unit="mm", start=0.0, min=-10.0, max=10.0, variability=fixed))
    v.append(Variable("rbf_width", "Float64", "parameter", "RBF network: width of the Gaussian units",
                      start=RBF_DEFAULTS["rbf_width"], min=1e-3, max=1e3, variability=fixed))
    for d in range(1, RBF_INPUTS + 1):
        v.append(Variable(f"rbf_offset_{d}", "Float64", "parameter",
                          f"RBF network: offset of input feature {d} (x = (feature - offset) * scale)",
                          start=RBF_DEFAULTS[f"rbf_offset_{d}"], min=-1e9, max=1e9, variability=fixed))
    for d in range(1, RBF_INPUTS + 1):
        v.append(Variable(f"rbf_scale_{d}", "Float64", "parameter", f"RBF network: scale of input feature {d}",
                          start=RBF_DEFAULTS[f"rbf_scale_{d}"], min=-1e9, max=1e9, variability=fixed))
    for j in range(1, RBF_HIDDEN + 1):
        for d in range(1, RBF_INPUTS + 1):
            v.append(Variable(f"rbf_center_{j}_{d}", "Float64", "parameter",
                              f"RBF network: coordinate {d} of the centre of unit {j}",
                              start=RBF_DEFAULTS[f"rbf_center_{j}_{d}"], min=-1e9, max=1e9, variability=fixed))
    for j in range(1, RBF_HIDDEN + 1):
        v.append(Variable(f"rbf_weight_{j}", "Float64", "parameter", f"RBF network: output weight of unit {j}",
                          start=RBF_DEFAULTS[f"rbf_weight_{j}"], min=-1e9, max=1e9, variability=fixed))
    v.append(Variable("rbf_bias", "Float64", "parameter", "RBF network: output bias",
                      start=RBF_DEFAULTS["rbf_bias"], min=-1e9, max=1e9, variability=fixed))
    v.append(Variable("feed_override", "Float64", "input", "Feed override (1 = 100 %; 0 = feed hold; not for G0)",
                      unit="1", display_unit="%", start=1.0, min=0.0, max=1.5))
    for axis in "xyz":
        v.append(Variable(axis, "Float64", "output", f"Machine {axis.upper()} position of the tool",
                          unit="m", display_unit="mm"))
    for axis in "xyz":
        v.append(Variable(f"{axis}_program", "Float64", "output",
                          f"Commanded {axis.upper()} position in work coordinates (before the work offset)",
                          unit="m", display_unit="mm"))
    for axis in "xyz":
        v.append(Variable(f"feed_velocity_{axis}", "Float64", "output", f"Feed velocity, {axis.upper()} component",
                          unit="m/s", display_unit="mm/min"))
    v += [
        Variable("feed", "Float64", "output", "Scheduled path speed", unit="m/s", display_unit="mm/min"),
        Variable("path_acceleration", "Float64", "output", "Scheduled tangential acceleration",
                 unit="m/s2", display_unit="mm/s2"),
        Variable("u", "Float64", "output", "NURBS parameter normalised over the curve's knot range (0..1) in NURBS "
                 "blocks, else the fraction of the block done"),
        Variable("line_number", "Int32", "output", "Line of the part program being executed (0 before the start)"),
        Variable("block_number", "Int32", "output", "N word of the block being executed (0 without one)"),
        Variable("spindle_speed", "Float64", "output", "Commanded spindle speed (negative for M4, 0 when stopped)",
                 unit="rad/s", display_unit="rpm"),
        Variable("spindle_on", "Boolean", "output", "Spindle running (M3/M4)"),
        Variable("rapid", "Boolean", "output", "A rapid move (G0) is being executed"),
        Variable("finished", "Boolean", "output", "The program has ended: the tool is at rest on its last point"),
        Variable("tool_number", "Int32", "output", "Active tool (T of the last tool change M6; 0 before it)"),
        Variable("tool_diameter", "Float64", "output", "Diameter of the active tool (tool table; 0 without an entry)",
                 unit="m", display_unit="mm"),
        Variable("tool_corner_radius", "Float64", "output", "Corner radius of the active tool (tool table)",
                 unit="m", display_unit="mm"),
        Variable("tool_length", "Float64", "output", "Length offset of the active tool (tool table, G43 H)",
                 unit="m", display_unit="mm"),
        Variable("tool_stick_out", "Float64", "output", "Stick-out of the active tool from its holder (tool table)",
                 unit="m", display_unit="mm"),
        Variable("tool_helix_angle", "Float64", "output", "Helix angle of the active tool's flutes (tool table)",
                 unit="rad", display_unit="deg"),
        Variable("tool_flutes", "Int32", "output", "Number of flutes of the active tool (tool table; 0 without)"),
        Variable("coolant", "Int32", "output", "Coolant: 0 off (M9), 1 mist (M7), 2 flood (M8), 3 both"),
        # last, so that the value references of the variables before it stay as they were
        Variable("lookahead_blocks", "Int32", "parameter",
                 "Blocks (moves) the feed schedule looks ahead over: planned at initialisation over the first "
                 "window, at rest at its end unless the program ends there, and re-planned as the middle of the "
                 "window is passed; a program of no more moves is planned whole (docs/interpolator.md)",
                 start=LOOKAHEAD_BLOCKS, min=2, max=parser.MAX_MOVES, variability=fixed),
    ]
    return tuple(v)


def _constants() -> tuple[tuple[str, int | float | tuple[float, ...]], ...]:
    """The constants fmus/interpolator/*.c share with the modules here, under the same names (model_constants.h)."""
    names = {numbers: ("MAX_SIGNIFICANT_DIGITS",),
             parser: ("MAX_LINE_LENGTH", "MAX_COORDINATE", "MAX_FEED_WORD", "MAX_SPEED_WORD",
                      "MAX_NURBS_POINTS", "MAX_DEGREE", "START_POINT_TOLERANCE", "ARC_RADIUS_TOLERANCE",
                      "ARC_RADIUS_RELATIVE", "MOVE_RAPID", "MOVE_LINE", "MOVE_ARC", "MOVE_NURBS", "MOVE_DWELL",
                      "COMP_OFF", "COMP_LEFT", "COMP_RIGHT", "COOLANT_OFF", "COOLANT_MIST", "COOLANT_FLOOD",
                      "COOLANT_BOTH", "DIALECT_FANUC", "DIALECT_LINUXCNC", "DIALECT_SINUMERIK", "MAX_MOVES",
                      "MAX_CALLED_LINES", "MAX_CALL_DEPTH", "MAX_REPEATS", "MAX_PROGRAM_NUMBER", "MAX_NOTES",
                      "NOTE_LENGTH", "PECK_CLEARANCE"),
             cutter_comp: ("COMP_TANGENT", "COMP_SMALL_TURN", "COMP_SLACK"),
             tool_table: ("MAX_TOOLS", "MAX_TOOL_NUMBER", "MAX_TOOL_NAME", "MAX_TOOL_VALUE"),
             nurbs: ("GL_NODES", "GL_WEIGHTS"),
             path: ("COS_TURN", "COUPLING_SPEED_SHARE", "CURVATURE_VARIATION", "SIGNIFICANT_TURN", "MAX_SAMPLE_DEPTH",
                    "MAX_SAMPLES",
                    "INITIAL_SUBDIVISION", "CHORD_SAFETY", "TANGENT_TOLERANCE", "BIG"),
             schedule: ("BISECTIONS", "VIOLATION_TOLERANCE"),
             param_update: ("METHOD_TAYLOR1", "METHOD_TAYLOR2", "METHOD_RBF", "METHOD_CORRECTOR", "RBF_HIDDEN",
                            "RBF_INPUTS", "MAX_NEWTON", "LANDING_SHARE")}
    return (("PI", math.pi),) + tuple((n, getattr(module, n)) for module, group in names.items() for n in group)


_NATIVE_OUTPUTS = (
    "x", "y", "z", "x_program", "y_program", "z_program", "feed_velocity_x", "feed_velocity_y", "feed_velocity_z",
    "feed", "path_acceleration", "u", "line_number", "block_number", "spindle_speed", "spindle_on", "rapid",
    "finished", "tool_number", "tool_diameter", "tool_corner_radius", "tool_length", "tool_stick_out",
    "tool_helix_angle", "tool_flutes", "coolant")

INTERPOLATOR = ModelDefinition(
    identifier="Interpolator",
    description="CNC interpolator: G-code with NURBS blocks to tool positions every interpolation period, "
                "with look-ahead feedrate scheduling and Taylor/RBF/predictor-corrector parameter update",
    default_step_size=1e-3,
    default_stop_time=10.0,
    equations=None,
    variables=_variables(),
    constants=_constants(),
    native_outputs=_NATIVE_OUTPUTS,
    # model.c interpolates in doStep (the feed override held over the step): at a communication point no output
    # depends directly on an input; in Initialization Mode the position is the start point (its G54 program
    # coordinates) and the other outputs are 0
    native_dependencies=tuple((n, ()) for n in _NATIVE_OUTPUTS),
    native_initial_dependencies=tuple((f"{a}{suffix}", (f"start_{a}",) + ((f"g54_{a}",) if suffix else ()))
                                      for a in "xyz" for suffix in ("", "_program")),
)

OUTPUTS = tuple(v.name for v in INTERPOLATOR.of("output"))
PARAMETERS = tuple(v.name for v in INTERPOLATOR.of("parameter") if v.type != "String")


def default_parameters() -> dict[str, float]:
    return {v.name: float(v.start) for v in INTERPOLATOR.of("parameter") if v.type != "String"}
