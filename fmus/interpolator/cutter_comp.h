/* Cutter radius compensation (G40/G41/G42): a stage after parsing that replaces the programmed XY contour of the
 * moves the parser marked with `comp` (COMP_LEFT/COMP_RIGHT) and `comp_radius` by the path of the tool centre, as
 * LinuxCNC does in the XY plane: a straight entry move to the first point offset perpendicular to it, lines offset
 * and arcs grown or shrunk by the radius, an arc around every outside corner (before a rapid a rapid straight
 * across it; at a turn of |sin| < COMP_SMALL_TURN the offset elements meet at their intersection near the corner
 * instead), inside corners at the intersection of the offset elements, a straight exit move after G40 from the
 * last compensated point. Refuses (naming the line) what cannot be followed without gouging, NURBS blocks, arcs
 * outside G17, entry or exit moves that are not straight, and a change of side or radius while compensation is
 * on. The Python reference, with the full description: models/interpolator/cutter_comp.py (bit-equal moves). */
#ifndef CUTTER_COMP_H
#define CUTTER_COMP_H

#include <stddef.h>

#include "gcode_parser.h"

/* the constants of models/interpolator/cutter_comp.py (tests/test_interpolator_cutter_comp.py checks they agree);
 * guarded so model_constants.h may generate them */
#ifndef COMP_TANGENT
#define COMP_TANGENT 1e-09 /* |sin| of a turn at or below which a junction is tangent */
#endif
#ifndef COMP_SMALL_TURN
#define COMP_SMALL_TURN 0.01 /* |sin| of an outside turn below which the offset elements meet (no arc) */
#endif
#ifndef COMP_SLACK
#define COMP_SLACK 1e-09 /* m: how far an inside-corner intersection may lie beyond an element's end */
#endif

/* Compensates `program` (the moves of gc_parse) in place. Returns 0, or -1 with `error` set to
 * "<file> line <n>: \"<text of that line>\": <what was expected>" (gc_line_error on `text`, `length` bytes) and
 * the program unchanged. Corner arcs take the line and the machine state of the move they precede. */
int cutter_compensate(GcProgram *program, const char *text, size_t length, const char *file, char *error,
                      size_t error_size);

#endif
