/* The interpolator engine: part program text -> a flat array of doubles (the FMU's instance heap: moves,
 * curves, path nodes, schedule pieces) plus flat structs (layout, state), then one interpolation point per
 * tick. Used by the FMU (model.c) and by the standalone tools (benchmark driver, fuzz harness). Mirrored by
 * models/interpolator/engine.py. */
#ifndef INTERPOLATOR_H
#define INTERPOLATOR_H

#include <stddef.h>
#include <stdint.h>

#include "feed_schedule.h"
#include "gcode_parser.h"
#include "param_update.h"
#include "path.h"

#define INTERP_MAGIC 1234567.0

/* A move's record in the heap: offsets in doubles (3-vectors take three), MOVE_DOUBLES in all. */
enum {
    MR_KIND = 0,         /* MOVE_RAPID .. MOVE_NURBS */
    MR_LINE = 1,         /* line of the part program */
    MR_S = 2,            /* path length at its start */
    MR_LENGTH = 3,
    MR_START = 4,        /* [3] machine coordinates */
    MR_END = 7,          /* [3] */
    MR_OFFSET = 10,      /* [3] work offset in effect */
    MR_FEED = 13,        /* programmed F, m/s */
    MR_SPINDLE = 14,     /* rad/s, signed */
    MR_SPINDLE_ON = 15,
    MR_CENTER = 16,      /* [3] arcs */
    MR_AXES = 19,        /* [3] arcs: in-plane a, b and the normal axis */
    MR_THETA0 = 22,
    MR_SWEEP = 23,
    MR_R0 = 24,
    MR_R1 = 25,
    MR_HEIGHT = 26,
    MR_CURVE = 27,       /* NURBS: index of the curve */
    MR_U0 = 28,
    MR_U1 = 29,
    MR_SPAN_LO = 30,
    MR_SPAN_HI = 31,
    MR_BLOCK = 32,       /* N word */
    MR_TOOL = 33,        /* active tool number */
    MR_COOLANT = 34,     /* COOLANT_OFF .. COOLANT_BOTH */
    MR_DWELL = 35,       /* MOVE_DWELL: seconds at rest */
    MR_EXACT_STOP = 36,  /* the path stops at the end of the move */
    MOVE_DOUBLES = 37
};

/* A tool's record in the heap (the tool table, copied at interp_prepare): SI units. */
enum {
    TR_NUMBER = 0,
    TR_DIAMETER = 1,
    TR_CORNER_RADIUS = 2,
    TR_LENGTH = 3,
    TR_STICK_OUT = 4,
    TR_HELIX = 5,
    TR_FLUTES = 6,
    TOOL_DOUBLES = 7
};

/* A curve's record in the heap (its control points and knots follow the records, from `points` on). */
enum {
    CR_DEGREE = 0,
    CR_LAST_POINT = 1, /* index of the last control point */
    CR_PW = 2,         /* heap offset of the homogeneous control points (4 per point) */
    CR_KNOTS = 3,      /* heap offset of the knots */
    CURVE_DOUBLES = 4
};

typedef struct {
    Limits limits; /* period, acceleration, jerk, centripetal, chord, axis limits */
    double max_feed, rapid_feed;
    UpdateSettings update;
    GcSettings gcode; /* start position, work offsets */
    size_t lookahead; /* blocks (moves) the feed schedule looks ahead over; 0: the whole program */
} InterpSettings;

/* Offsets (in doubles) into the heap and counts: flat, part of the FMU state. */
typedef struct {
    size_t heap_size;
    size_t lookahead; /* blocks of the look-ahead window (0 or >= n_moves: the whole program at once) */
    size_t n_moves, n_curves, n_nodes, n_ints, piece_capacity, n_tools;
    size_t moves, curves, points, tools, node_s, node_vh, node_left, node_right, station, int_move, int_at, int_jt, int_cap,
        pieces;
    double total;
    int final_line, final_block, final_spindle_on;
    double final_spindle;
    double start[3], start_offset[3];
} InterpLayout;

typedef struct {
    double x[3], program[3], velocity[3];
    double feed, acceleration, u, spindle;
    int line, block, spindle_on, rapid, finished;
    int tool, coolant; /* of the move being executed (the last move's once finished) */
    /* the geometry of `tool` from the tool table (0 for tool 0 and for a tool the table does not have) */
    double tool_diameter, tool_corner_radius, tool_length, tool_stick_out, tool_helix;
    int tool_flutes;
} InterpOutputs;

typedef struct {
    int64_t tick;
    size_t piece, n_pieces, move;
    double s, v, a;
    int finished, hold, planned;
    double end_time, override;
    /* the look-ahead window of the plan: its last node (the plan ends at rest there), whether that is the program's
     * end, and the path length from which on the next window is planned */
    size_t window_end;
    int at_end;
    double replan_s;
    NurbsState nurbs;
    InterpOutputs out;
} InterpState;

typedef struct {
    GcProgram program;
    PathBuild path;
    GcTool *tools; /* a copy of the tool table */
    size_t n_tools;
    size_t lookahead;       /* settings->lookahead */
    size_t window_intervals; /* the most intervals any window of `lookahead` moves holds */
} InterpPrepared;

/* Parse and build the path; on error -1 with the message in `error`. Release with interp_release. */
int interp_prepare(const char *text, size_t length, const char *file, const InterpSettings *settings,
                   InterpPrepared *prepared, char *error, size_t error_size);
size_t interp_heap_size(const InterpPrepared *prepared);
/* Fill a zeroed heap of interp_heap_size doubles and the layout, giving back the prepared moves and path as they
 * are copied (the program is never held twice whole); interp_release frees what is left. */
void interp_install(InterpPrepared *prepared, double *heap, InterpLayout *layout);
void interp_release(InterpPrepared *prepared);

/* Outputs before the program starts: the tool at its start position. */
void interp_initial_outputs(const InterpSettings *settings, InterpOutputs *out);
void interp_start(InterpState *state, const InterpSettings *settings);
/* Plans (first call) or re-plans from the next zero-acceleration moment after the last tick when the
 * override differs from the planned one. Each plan covers the look-ahead window: the moves from the one at its
 * start on, settings->lookahead of them (the whole program when it has no more), at rest at the window's end
 * unless the program ends there. -1 when out of memory. */
int interp_set_override(double *heap, const InterpLayout *layout, InterpState *state, const InterpSettings *settings,
                        double override);
/* One interpolation period; first, once the path passed the middle of the look-ahead window, the next window is
 * planned (from the next zero-acceleration moment, as for an override). -1 when out of memory. */
int interp_tick(double *heap, const InterpLayout *layout, InterpState *state, const InterpSettings *settings);
/* Consistency of a layout and state with a heap (an FMU state from outside): 0 if usable. */
int interp_check(const double *heap, size_t heap_size, const InterpLayout *layout, const InterpState *state);
/* 1 when the feed is held, the tool stands still on the last piece of the plan and the tick from `before` to
 * `after` changed nothing but the tick count: every further tick would do the same. */
int interp_holds_still(const double *heap, const InterpLayout *layout, const InterpState *before,
                       const InterpState *after);

#endif
