"""Interpolator: the CNC's real-time interpolator as an FMU — part program in, tool positions every
interpolation period out (``fmus/interpolator/``, identifier ``Interpolator``).

This package is (1) the model definition ``INTERPOLATOR`` (variables, units, ranges, defaults) and (2) the
Python reference implementation of everything the FMU's C code computes natively, written operation for
operation like the C code so that the generic FMU tests compare the two to 1e-12 and
``tests/test_interpolator*.py`` prove the C code right. One module per C file of ``fmus/interpolator/``:

- ``definition``: ``INTERPOLATOR``, its variables and default parameters (``model_generated.h``);
- ``parser``: the G-code subset and its parser (``gcode_parser.c``; the subset is documented there);
- ``nurbs``: NURBS evaluation and arc length (``nurbs.c``);
- ``path``: moves, NURBS samples and velocity limits along the path (``path.c``);
- ``schedule``: look-ahead feedrate schedule, jerk-limited S-curves (``feed_schedule.c``);
- ``param_update``: Taylor and RBF parameter update (``param_update.c``);
- ``engine``: the interpolator tick by tick, with the corrector (``interpolator.c``);
- ``fmu``: what the FMU adds (default program, ticks per step) and the reference for the generic FMU tests
  (``model.c``).

Every public name of these modules is importable from here (``from milling_twin.models import
interpolator as ip; ip.Interpolator``). Feedrate schedule, parameter update: see ``Path``, ``Schedule``
and ``step_nurbs``, and docs/interpolator.md.
"""
from __future__ import annotations

from milling_twin.models.interpolator.definition import (INTERPOLATOR, JERK_UNIT, OUTPUTS, PARAMETERS, RBF_DEFAULTS,
                                                         default_parameters)
from milling_twin.models.interpolator.engine import Interpolator
from milling_twin.models.interpolator.fmu import (RESOURCE_PROGRAM, default_program_header, default_program_text,
                                                  initial_outputs, random_arguments, reference_trajectory, ticks_in)
from milling_twin.models.interpolator.nurbs import (GL_NODES, GL_WEIGHTS, Nurbs, arc_length_derivatives,
                                                    basis_derivatives, find_span, gauss_length)
from milling_twin.models.interpolator.param_update import (MAX_NEWTON, METHOD_CORRECTOR, METHOD_NAMES, METHOD_RBF,
                                                           METHOD_TAYLOR1, METHOD_TAYLOR2, RBF_HIDDEN, RBF_INPUTS,
                                                           NurbsState, Rbf, predict, rbf_features, rbf_of,
                                                           rbf_output, taylor_step)
from milling_twin.models.interpolator.numbers import MAX_SIGNIFICANT_DIGITS
from milling_twin.models.interpolator.parser import (ARC_RADIUS_RELATIVE, ARC_RADIUS_TOLERANCE, MAX_COORDINATE,
                                                     MAX_DEGREE, MAX_FEED_WORD, MAX_LINE_LENGTH, MAX_NURBS_POINTS,
                                                     MAX_SPEED_WORD, MOVE_ARC, MOVE_LINE,
                                                     MOVE_NURBS, MOVE_RAPID, OFFSET_NAMES, START_POINT_TOLERANCE,
                                                     Move, NurbsCurve, Program, ProgramError, nurbs_block_gcode,
                                                     parse_program)
from milling_twin.models.interpolator.path import (BIG, CHORD_SAFETY, COS_TURN, CURVATURE_VARIATION,
                                                   INITIAL_SUBDIVISION, MAX_SAMPLE_DEPTH, MAX_SAMPLES,
                                                   SIGNIFICANT_TURN, TANGENT_TOLERANCE, ArcShape, Geometry, Limits,
                                                   Path, PathError, build_path, conservative_limits, curvature_limit,
                                                   junction_limit, limits_of, line_geometry, tangential_limits)
from milling_twin.models.interpolator.schedule import (BISECTIONS, VIOLATION_TOLERANCE, Piece, Schedule, Segment,
                                                       lowest_feasible, reach_up, s_curve_distance,
                                                       s_curve_position, s_curve_time, segment_peak)

__all__ = [
    "INTERPOLATOR", "JERK_UNIT", "OUTPUTS", "PARAMETERS", "RBF_DEFAULTS", "default_parameters",
    "Interpolator",
    "RESOURCE_PROGRAM", "default_program_header", "default_program_text", "initial_outputs", "random_arguments",
    "reference_trajectory", "ticks_in",
    "GL_NODES", "GL_WEIGHTS", "Nurbs", "arc_length_derivatives", "basis_derivatives", "find_span", "gauss_length",
    "MAX_NEWTON", "METHOD_CORRECTOR", "METHOD_NAMES", "METHOD_RBF", "METHOD_TAYLOR1", "METHOD_TAYLOR2", "RBF_HIDDEN",
    "RBF_INPUTS", "NurbsState", "Rbf", "predict", "rbf_features", "rbf_of", "rbf_output", "taylor_step",
    "ARC_RADIUS_RELATIVE", "ARC_RADIUS_TOLERANCE", "MAX_COORDINATE", "MAX_DEGREE", "MAX_FEED_WORD", "MAX_LINE_LENGTH",
    "MAX_NURBS_POINTS", "MAX_SIGNIFICANT_DIGITS", "MAX_SPEED_WORD", "MOVE_ARC", "MOVE_LINE", "MOVE_NURBS",
    "MOVE_RAPID", "OFFSET_NAMES", "START_POINT_TOLERANCE", "Move", "NurbsCurve", "Program", "ProgramError",
    "nurbs_block_gcode", "parse_program",
    "BIG", "CHORD_SAFETY", "COS_TURN", "CURVATURE_VARIATION", "INITIAL_SUBDIVISION", "MAX_SAMPLE_DEPTH",
    "MAX_SAMPLES", "SIGNIFICANT_TURN", "TANGENT_TOLERANCE", "ArcShape", "Geometry", "Limits", "Path", "PathError",
    "build_path", "conservative_limits", "curvature_limit", "junction_limit", "limits_of", "line_geometry",
    "tangential_limits",
    "BISECTIONS", "VIOLATION_TOLERANCE", "Piece", "Schedule", "Segment", "lowest_feasible", "reach_up",
    "s_curve_distance", "s_curve_position", "s_curve_time", "segment_peak",
]
