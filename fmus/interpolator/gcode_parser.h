/* G-code parser of the interpolator: part program text -> moves (lines, arcs, NURBS pieces) in machine
 * coordinates (m), as documented in models/interpolator/parser.py (the Python reference of this file). */
#ifndef GCODE_PARSER_H
#define GCODE_PARSER_H

#include <stddef.h>

/* MOVE_RAPID..MOVE_NURBS, MAX_DEGREE, MAX_LINE_LENGTH and the parser's limits: generated from
 * models/interpolator/ */
#include "model_constants.h"

/* The parser's limits of program structure (models/interpolator/parser.py, same names and values; to be generated
 * into model_constants.h like the others: tests/test_interpolator_programs.py checks they agree) */
#ifndef MAX_MOVES
#define MAX_MOVES 1000000
#define MAX_CALLED_LINES 1000000
#define MAX_CALL_DEPTH 8
#define MAX_REPEATS 9999
#define MAX_PROGRAM_NUMBER 99999999
#define MAX_NOTES 32
#define NOTE_LENGTH 200
#define PECK_CLEARANCE 0.000254
#endif

typedef struct {
    int kind;
    int line;
    int block; /* N word, 0 without */
    double start[3], end[3], offset[3];
    double feed;    /* programmed F, m/s (rapids: 0) */
    double spindle; /* rad/s, signed */
    int spindle_on;
    /* arc */
    double center[3];
    int axes[3]; /* in-plane a, b and the normal axis */
    double theta0, sweep, r0, r1, height;
    /* NURBS */
    int curve;
    double u0, u1;
    /* machine state while the move runs */
    int tool;       /* active tool number (T.. M6), 0 before the first tool change */
    int coolant;    /* COOLANT_OFF, COOLANT_MIST (M7), COOLANT_FLOOD (M8), COOLANT_BOTH */
    int exact_stop; /* 1: the path stops at the end of this move (G61, G9, the last move before a dwell) */
    double dwell;   /* MOVE_DWELL: seconds the tool stands still at `start` (== `end`) */
    double tolerance; /* contour tolerance of G64 P / CYCLE832, m; 0: the chord_error parameter */
    int comp;         /* cutter radius compensation: COMP_OFF (G40), COMP_LEFT (G41), COMP_RIGHT (G42) */
    double comp_radius; /* m: the radius the tool path is offset by (tool table radius of D) */
} GcMove;

/* One row of the tool table (SI units); `number` is the T word. */
typedef struct {
    int number;
    char name[32]; /* Sinumerik T="name"; empty without */
    double diameter, corner_radius, length, stick_out, helix;
    int flutes;
} GcTool;

typedef struct {
    int degree;
    int n_points;
    int line;
    double *points;  /* 3 per control point, machine coordinates */
    double *weights; /* n_points */
    double *knots;   /* n_points + degree + 1 */
} GcCurve;

typedef struct {
    GcMove *moves;
    size_t n_moves, cap_moves;
    GcCurve *curves;
    size_t n_curves, cap_curves;
    int final_line, final_block;
    double final_spindle;
    int final_spindle_on;
    double start[3], start_offset[3];
    /* accepted but not modelled words, one note per word: "<file> line <n>: \"<text>\": <what>" */
    char notes[MAX_NOTES][NOTE_LENGTH];
    int n_notes;
} GcProgram;

typedef struct {
    double start[3];      /* machine position before the program */
    double offsets[6][3]; /* G54..G59 */
    double home[3];       /* machine position of the reference point (G28) */
    int dialect;          /* DIALECT_FANUC, DIALECT_LINUXCNC, DIALECT_SINUMERIK */
    const GcTool *tools;  /* the tool table (may be NULL when n_tools is 0); not owned */
    size_t n_tools;
} GcSettings;

/* Parses `length` bytes of `text`. Returns 0 and fills `program` (free with gc_free), or -1 with the
 * message "<file> line <n>: \"<text>\": <what was expected>" in `error` (program left empty). */
int gc_parse(const char *text, size_t length, const char *file, const GcSettings *settings, GcProgram *program,
             char *error, size_t error_size);
void gc_free(GcProgram *program);

/* The parser's message format for a later stage that refuses a line of the program (cutter compensation):
 * "<file> line <n>: \"<text of that line, at most 80 characters, non-printable shown as ?>\": <expected>". */
void gc_line_error(const char *text, size_t length, const char *file, size_t line, const char *expected,
                   char *error, size_t error_size);

#endif
