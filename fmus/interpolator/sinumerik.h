/* Sinumerik 840D part programs, translated line by line into the core G-code syntax of gcode_parser.c.
 * The Python reference is models/interpolator/sinumerik.py (what is translated, what is refused and the
 * Siemens manuals relied on are listed in its docstring); both give the same output bytes and the same messages.
 *
 * Use (the parser, for dialect == DIALECT_SINUMERIK):
 *   SinState s;  sin_init(&s, tools, n_tools);  sin_prescan(&s, text, length);
 *   for each line: sin_translate_line(&s, line, line_length, out, sizeof out, expected, sizeof expected)
 *       0: `out` holds ONE line in the core syntax (possibly empty) to parse in place of the original line;
 *          state.note holds what the line used for the first time that is accepted but not modelled ("" if none);
 *      -1: `expected` holds what was expected; the caller reports "<file> line <n>: \"<original text>\": <expected>".
 *   at the end of the text: sin_finish(&s, expected, size): -1 if a B spline is still open.
 * `out` needs SIN_MAX_OUTPUT + 1 bytes; the state holds no pointers it owns (the tool table is the caller's and
 * must outlive the translation); copying or discarding it is free. */
#ifndef SINUMERIK_H
#define SINUMERIK_H

#include <stddef.h>

#include "gcode_parser.h" /* GcTool */

#define SIN_R_COUNT 100
#define SIN_MAX_SUBPROGRAMS 64
#define SIN_NAME_LENGTH 31 /* characters of a subprogram or tool name */
#define SIN_MAX_OUTPUT 2000
#define SIN_MAX_NESTING 32
#define SIN_MAX_WORD 64
#define SIN_MAX_TOKENS 256
#define SIN_FIRST_SUBPROGRAM 9001
#define SIN_NOTE_SIZE 2048

typedef struct {
    double r[SIN_R_COUNT];
    unsigned char r_set[SIN_R_COUNT];
    int r_section[SIN_R_COUNT]; /* program section of each R parameter's last assignment */
    int section;                /* 0: the main program, 1 + index: a subprogram */
    double frame[3]; /* TRANS/ATRANS totals, program units */
    const GcTool *tools; /* not owned */
    size_t n_tools;
    char subprograms[SIN_MAX_SUBPROGRAMS][SIN_NAME_LENGTH + 1]; /* upper case; number SIN_FIRST_SUBPROGRAM + index */
    int n_subprograms;
    int spline;      /* BSPLINE is the motion mode */
    int spline_open; /* a G5.2 block is open */
    int degree;      /* SD */
    int tool;        /* the last T */
    int active;      /* the tool of the last M6 */
    int edge;        /* the active D: 0 or 1 */
    /* the program section where the frame, the active tool and D were last set (-1 after a subprogram call: the
     * state then depends on the call, which the translation in file order cannot follow) */
    int frame_section, active_section, edge_section;
    double adis;
    int blend; /* G641..G645 active */
    char after_header[SIN_NAME_LENGTH + 1]; /* subprogram whose %_N_..._SPF header was the last line with content */
    unsigned long noted;                    /* one bit per accepted, not modelled word already reported */
    char note[SIN_NOTE_SIZE];
} SinState;

void sin_init(SinState *state, const GcTool *tools, size_t n_tools);
/* Numbers the subprograms of the whole text (section headers %_N_<NAME>_SPF, PROC lines) in order of appearance,
 * so a call may come before the section. */
void sin_prescan(SinState *state, const char *text, size_t length);
int sin_translate_line(SinState *state, const char *line, size_t length, char *out, size_t out_size, char *expected,
                       size_t expected_size);
int sin_finish(const SinState *state, char *expected, size_t expected_size);

#endif
