/* G-code parser: the subset documented in models/interpolator/parser.py, line by line, with the
 * same checks and the same arithmetic as that reference. Every malformed line is an error naming the line,
 * its text and what was expected; nothing is skipped. Bounded work per byte: safe on any input (fuzzed). */
#include "gcode_parser.h"

#include "cutter_comp.h"
#include "gcode_number.h"
#include "sinumerik.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define MAX_WORDS 512


typedef struct {
    char letter;
    double value;
    const char *text; /* the number as written (points into the line) */
    int text_length;
} Word;

/* one value per letter: present flag, value, text */
typedef struct {
    int present;
    double value;
    const char *text;
    int text_length;
} Slot;

enum {
    G_MOTION, G_CYCLE, G_NON_MODAL, G_G9, G_PLANE, G_UNITS, G_COMP, G_LENGTH, G_OFFSET, G_PATH, G_DISTANCE, G_FEED,
    G_RETRACT, G_CANCEL, G_NURBS_END, G_GROUPS
};
enum { M_STOP, M_END, M_SPINDLE, M_TOOL_CHANGE, M_COOLANT, M_SUBPROGRAM, M_GROUPS };
static const char *const G_GROUP_NAMES[G_GROUPS] = {"motion", "cycle", "non-modal", "g9", "plane", "units",
                                                    "compensation", "length", "offset", "path", "distance", "feed",
                                                    "retract", "cancel", "nurbs end"};
static const char *const M_GROUP_NAMES[M_GROUPS] = {"stop", "end", "spindle", "tool change", "coolant", "subprogram"};

/* G codes (10 * number) and their groups, as _G_GROUPS of parser.py */
static const int G_CODES[][2] = {
    {0, G_MOTION},      {10, G_MOTION},     {20, G_MOTION},     {30, G_MOTION},     {50, G_MOTION},
    {51, G_MOTION},     {52, G_MOTION},
    {53, G_NURBS_END},  {62, G_MOTION},     {730, G_MOTION},    {810, G_MOTION},    {820, G_MOTION},
    {830, G_MOTION},    {800, G_CYCLE},     {40, G_NON_MODAL},  {100, G_NON_MODAL}, {280, G_NON_MODAL},
    {520, G_NON_MODAL}, {530, G_NON_MODAL}, {90, G_G9},         {170, G_PLANE},     {180, G_PLANE},
    {190, G_PLANE},     {200, G_UNITS},     {210, G_UNITS},     {400, G_COMP},      {410, G_COMP},
    {420, G_COMP},      {430, G_LENGTH},    {440, G_LENGTH},    {490, G_LENGTH},    {540, G_OFFSET},
    {550, G_OFFSET},    {560, G_OFFSET},    {570, G_OFFSET},    {580, G_OFFSET},    {590, G_OFFSET},
    {5000, G_OFFSET},   {610, G_PATH},      {611, G_PATH},      {640, G_PATH},      {900, G_DISTANCE},
    {910, G_DISTANCE},  {940, G_FEED},      {950, G_FEED},      {980, G_RETRACT},   {990, G_RETRACT},
    {150, G_CANCEL},    {500, G_CANCEL},    {501, G_CANCEL},    {690, G_CANCEL}};
static const char G_LIST[] = "G0 G1 G2 G3 G4 G5 G5.1 G5.2 G5.3 G6.2 G9 G10 G15 G17 G18 G19 G20 G21 G28 G40 G41 G42 "
                             "G43 G44 G49 G50 G50.1 G52 G53 G54-G59 G61 G61.1 G64 G69 G73 G80 G81 G82 G83 G90 G91 G94 "
                             "G95 G98 G99";
static const int M_CODES[][2] = {{0, M_STOP},      {1, M_STOP},        {2, M_END},         {30, M_END},
                                 {3, M_SPINDLE},   {4, M_SPINDLE},     {5, M_SPINDLE},     {19, M_SPINDLE},
                                 {6, M_TOOL_CHANGE}, {7, M_COOLANT},   {8, M_COOLANT},     {9, M_COOLANT},
                                 {98, M_SUBPROGRAM}, {99, M_SUBPROGRAM}};
static const char M_LIST[] = "M0 M1 M2 M3 M4 M5 M6 M7 M8 M9 M19 M30 M98 M99";
static const char LETTER_LIST[] = "G, M, N, O, T, X, Y, Z, I, J, K, R, F, S, P, L, H, D or Q";

static int is_cycle(int code) { return code == 730 || code == 810 || code == 820 || code == 830; }

typedef struct {
    long number; /* O number, -1 for the text before the first O line */
    size_t o_line; /* 1-based line of the O line, 0 for the text before it */
    size_t end;    /* 1-based line of the next O line (or n_lines + 1) */
    int subprogram;
} Section;

typedef struct {
    size_t section, return_to, line;
    long remaining;
} Call;

typedef struct {
    const char *text; /* the text parsed: the file's, or its translation in the sinumerik dialect */
    size_t length;
    const char *file;
    /* the file's lines, quoted by messages (the same as the parsed ones except in the sinumerik dialect) */
    const char *raw_text;
    size_t *raw_start, *raw_length;
    char *translated;
    size_t closing_line; /* the G5.3 line of the last G5.2 block: its other words run after the block */
    /* line index: start offset and length of each line (without '\n' and a trailing '\r') */
    size_t *line_start;
    size_t *line_length;
    size_t n_lines;
    char *error;
    size_t error_size;
    GcProgram *program;
    double offsets[6][3];
    int active_offset; /* -1: G500 (no settable offset) */
    double local[3];   /* G52 */
    double length_offset;
    double home[3];
    int dialect;
    const GcTool *tools;
    size_t n_tools;
    double position[3];
    int inch, absolute, plane, motion;
    double feed, speed;
    int per_rev;
    double feed_rev;
    int spindle_dir;
    int tool, pending_tool, coolant, exact_mode, g9, comp, retract_r;
    double tolerance, comp_radius;
    int has_cycle_r, has_cycle_z;
    double cycle_r, cycle_z, cycle_q, cycle_p, cycle_initial;
    char noted[MAX_NOTES][16];
    int n_noted;
    int ended;
    int block;
    Section *sections;
    size_t n_sections, main_section;
    long *section_at; /* per line: the index of the section its O line starts, -1 */
    Call stack[MAX_CALL_DEPTH];
    int depth;
    size_t called_lines;
    int has_last_pq; /* after a G5: the move count then and its P, Q (m) */
    size_t last_pq_moves;
    double last_pq[2];
    /* the current line's words */
    Word words[MAX_WORDS];
    int n_words;
    Slot slots[26];
    int g[G_GROUPS];
    int m[M_GROUPS];
    const char *g_text[G_GROUPS];
    int g_text_length[G_GROUPS];
} Parser;

static void fail_at(Parser *p, size_t line, const char *format, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 3, 4)))
#endif
    ;

/* "<file> line <n>: \"<raw, clipped to 80 characters, non-printable as ?>\": <expected>" */
static void format_line_error(const char *raw, size_t raw_length, const char *file, size_t line,
                              const char *expected, char *error, size_t error_size) {
    char shown[96];
    size_t i, n = 0;
    for (i = 0; i < raw_length && n < 80; i++, n++) {
        unsigned char c = (unsigned char)raw[i];
        shown[n] = (c >= 32 && c < 127) ? (char)c : '?';
    }
    if (raw_length > 80) memcpy(shown + 77, "...", 3), n = 80;
    shown[n] = '\0';
    snprintf(error, error_size, "%s line %zu: \"%s\": %s", file, line, shown, expected);
}

void gc_line_error(const char *text, size_t length, const char *file, size_t line, const char *expected,
                   char *error, size_t error_size) {
    size_t i, start = 0, k = 1, n = 0;
    for (i = 0; i < length && k < line; i++)
        if (text[i] == '\n') k++, start = i + 1;
    if (line >= 1 && k == line) {
        while (start + n < length && text[start + n] != '\n') n++;
        if (n > 0 && text[start + n - 1] == '\r') n--;
    }
    format_line_error(text + start, n, file, line, expected, error, error_size);
}

static void fail_at(Parser *p, size_t line, const char *format, ...) {
    char expected[512];
    int known = line >= 1 && line <= p->n_lines;
    va_list args;
    va_start(args, format);
    vsnprintf(expected, sizeof expected, format, args);
    va_end(args);
    format_line_error(known ? p->raw_text + p->raw_start[line - 1] : "", known ? p->raw_length[line - 1] : 0,
                      p->file, line, expected, p->error, p->error_size);
}

static double length_of(const Parser *p, double value) { return p->inch ? value * 0.0254 : value / 1000.0; }
static double unit_factor(const Parser *p) { return p->inch ? 0.0254 : 1e-3; }

static int is_letter(char c) { return (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z'); }

/* The number after a letter (spaces allowed before it); -1 on error (reported). */
static int parse_number(Parser *p, size_t line, const char *s, size_t n, size_t *i, char letter, double *value,
                        const char **text, int *text_length) {
    size_t start;
    NumberStatus status;
    while (*i < n && (s[*i] == ' ' || s[*i] == '\t')) (*i)++;
    start = *i;
    status = gc_read_number(s, n, i, value);
    if (status != NUMBER_OK) {
        char what[4] = {'\'', letter, '\'', '\0'}, expected[128];
        gc_number_expected(status, what, expected, sizeof expected);
        fail_at(p, line, "%s", expected);
        return -1;
    }
    *text = s + start;
    *text_length = (int)(*i - start);
    return 0;
}

/* Words of line `line` (1-based); 0 ok (n_words may be 0), -1 error. */
static int tokenize(Parser *p, size_t line) {
    const char *s = p->text + p->line_start[line - 1];
    size_t n = p->line_length[line - 1], i = 0;
    p->n_words = 0;
    while (i < n) {
        char c = s[i];
        if (c == ' ' || c == '\t') {
            i++;
        } else if (c == '(') {
            size_t j = i + 1;
            while (j < n && s[j] != ')') {
                if (s[j] == '(') {
                    fail_at(p, line, "')' before another '(' (comments do not nest)");
                    return -1;
                }
                j++;
            }
            if (j >= n) {
                fail_at(p, line, "')' to close the comment");
                return -1;
            }
            i = j + 1;
        } else if (c == ';') {
            break;
        } else if (is_letter(c) || (c == ':' && p->n_words == 0)) {
            char letter = c == ':' ? 'O' : (char)(c >= 'a' ? c - 'a' + 'A' : c);
            Word *w;
            if (!strchr("GMNXYZIJKRFSPLOTHDQ", letter)) {
                fail_at(p, line, "a word %s, got '%c'%s", LETTER_LIST, c,
                        strchr("ABCUVW", letter) ? " (only the axes X, Y, Z are modelled)" : "");
                return -1;
            }
            if (p->n_words >= MAX_WORDS) { /* cannot happen: a word takes two characters of a short line */
                fail_at(p, line, "at most %d words in a line", MAX_WORDS);
                return -1;
            }
            w = &p->words[p->n_words];
            i++;
            if (parse_number(p, line, s, n, &i, letter, &w->value, &w->text, &w->text_length) != 0) return -1;
            w->letter = letter;
            p->n_words++;
        } else {
            unsigned char b = (unsigned char)c;
            if (b >= 32 && b < 127)
                fail_at(p, line, "a word (letter and number), a comment or the end of the line, got '%c'%s", c,
                        (c == '#' || c == '[') ? " (parameters and expressions are not supported)" : "");
            else if (b < 128)
                fail_at(p, line, "a word (letter and number), a comment or the end of the line, got byte 0x%02x", b);
            else
                fail_at(p, line, "a word (letter and number), a comment or the end of the line, got a non-ASCII "
                                 "character");
            return -1;
        }
    }
    return 0;
}

/* A line holding only '%' (blanks around it allowed). */
static int is_tape_mark(const Parser *p, size_t line) {
    const char *s = p->text + p->line_start[line - 1];
    size_t n = p->line_length[line - 1], i = 0, marks = 0;
    for (i = 0; i < n; i++) {
        if (s[i] == '%')
            marks++;
        else if (s[i] != ' ' && s[i] != '\t')
            return 0;
    }
    return marks == 1;
}

/* Block skip: a line whose first character (after blanks) is '/' (block delete on). */
static int is_skipped(const Parser *p, size_t line) {
    const char *s = p->text + p->line_start[line - 1];
    size_t n = p->line_length[line - 1], i = 0;
    while (i < n && (s[i] == ' ' || s[i] == '\t')) i++;
    return i < n && s[i] == '/';
}

/* G code as 10 * number (G6.2 -> 62) and its group in *group; -1 for an unknown code (reported). */
static int g_code(Parser *p, size_t line, const Word *w, int *group) {
    double tenths_value = w->value * 10.0;
    long tenths = w->value >= 0.0 && w->value < 1e5 ? (long)floor(tenths_value + 0.5) : -1;
    size_t k;
    if (tenths >= 0 && fabs(tenths_value - (double)tenths) <= 1e-9)
        for (k = 0; k < sizeof G_CODES / sizeof G_CODES[0]; k++)
            if (G_CODES[k][0] == tenths) {
                *group = G_CODES[k][1];
                return (int)tenths;
            }
    fail_at(p, line, "a supported G code (%s), got G%.*s", G_LIST, w->text_length, w->text);
    return -1;
}

static Slot *slot(Parser *p, char letter) { return &p->slots[letter - 'A']; }
static int has(Parser *p, char letter) { return p->slots[letter - 'A'].present; }
static double val(Parser *p, char letter) { return p->slots[letter - 'A'].value; }

static int grow_moves(Parser *p) {
    GcProgram *g = p->program;
    if (g->n_moves == g->cap_moves) {
        size_t cap = g->cap_moves ? 2 * g->cap_moves : 64;
        GcMove *m = realloc(g->moves, cap * sizeof *m);
        if (!m) {
            snprintf(p->error, p->error_size, "%s: out of memory for %zu moves", p->file, cap);
            return -1;
        }
        g->moves = m;
        g->cap_moves = cap;
    }
    return 0;
}

static void spindle_now(const Parser *p, double *speed, int *on) {
    *speed = p->speed * (2.0 * PI / 60.0) * (double)p->spindle_dir;
    *on = p->spindle_dir != 0;
}

/* Machine position of the programmed zero: work offset + G52 + tool length (Z). */
static void total_offset(const Parser *p, double out[3]) {
    static const double none[3] = {0.0, 0.0, 0.0};
    const double *off = p->active_offset >= 0 ? p->offsets[p->active_offset] : none;
    int a;
    for (a = 0; a < 3; a++) out[a] = p->local[a] != 0.0 ? off[a] + p->local[a] : off[a];
    if (p->length_offset != 0.0) out[2] = out[2] + p->length_offset;
}

static double current_feed(const Parser *p) { return p->per_rev ? p->feed_rev * p->speed / 60.0 : p->feed; }

/* A new move with the machine state stamped on it (the caller sets its end; the position follows it). */
static GcMove *new_move(Parser *p, int kind, size_t line) {
    GcMove *m;
    if (p->program->n_moves >= MAX_MOVES) {
        fail_at(p, line, "at most %d moves in a program (subprogram repeats and canned cycles included)", MAX_MOVES);
        return NULL;
    }
    if (grow_moves(p) != 0) return NULL;
    m = &p->program->moves[p->program->n_moves++];
    memset(m, 0, sizeof *m);
    m->kind = kind;
    m->line = (int)line;
    m->block = p->block;
    memcpy(m->start, p->position, sizeof m->start);
    total_offset(p, m->offset);
    spindle_now(p, &m->spindle, &m->spindle_on);
    m->curve = -1;
    m->axes[0] = 0, m->axes[1] = 1, m->axes[2] = 2;
    m->tool = p->tool;
    m->coolant = p->coolant;
    m->exact_stop = p->exact_mode || p->g9;
    m->tolerance = p->tolerance;
    m->comp = p->comp;
    m->comp_radius = p->comp_radius;
    return m;
}

/* "<file> line <n>: \"<text>\": <what>" once per key (accepted but not modelled). */
static void note(Parser *p, size_t line, const char *key, const char *format, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 4, 5)))
#endif
    ;
static void note(Parser *p, size_t line, const char *key, const char *format, ...) {
    char what[256];
    int k;
    va_list args;
    GcProgram *g = p->program;
    if (g->n_notes >= MAX_NOTES) return;
    for (k = 0; k < p->n_noted; k++)
        if (strcmp(p->noted[k], key) == 0) return;
    snprintf(p->noted[p->n_noted++], sizeof p->noted[0], "%s", key);
    va_start(args, format);
    vsnprintf(what, sizeof what, format, args);
    va_end(args);
    format_line_error(p->raw_text + p->raw_start[line - 1], p->raw_length[line - 1], p->file, line, what,
                      g->notes[g->n_notes], NOTE_LENGTH);
    g->n_notes++;
}

static int check_coordinate(Parser *p, size_t line, double value) {
    if (fabs(value) > MAX_COORDINATE) {
        fail_at(p, line, "a coordinate of magnitude at most %g", MAX_COORDINATE);
        return -1;
    }
    return 0;
}

static int target(Parser *p, size_t line, double end[3]) {
    static const char axes[3] = {'X', 'Y', 'Z'};
    double off[3];
    int a;
    total_offset(p, off);
    for (a = 0; a < 3; a++) {
        double value;
        if (!has(p, axes[a])) {
            end[a] = p->position[a];
            continue;
        }
        value = val(p, axes[a]);
        if (check_coordinate(p, line, value) != 0) return -1;
        end[a] = p->absolute ? length_of(p, value) + off[a] : p->position[a] + length_of(p, value);
    }
    return 0;
}

/* A NURBS control point from the line's X, Y, Z (absolute, program units, plus the offset `off`); an axis not
 * written keeps the previous control point's coordinate. -1 on error (reported). */
static int control_point(Parser *p, size_t line, const double off[3], const double previous[3], double pt[3]) {
    static const char axes[3] = {'X', 'Y', 'Z'};
    int a;
    for (a = 0; a < 3; a++) {
        if (has(p, axes[a])) {
            double value = val(p, axes[a]);
            if (check_coordinate(p, line, value) != 0) return -1;
            pt[a] = length_of(p, value) + off[a];
        } else {
            pt[a] = previous[a];
        }
    }
    return 0;
}

static int need_feed(Parser *p, size_t line) {
    if ((p->per_rev ? p->feed_rev : p->feed) <= 0.0) {
        fail_at(p, line, "F (feed) before the first feed move (G1, G2, G3, G6.2)");
        return -1;
    }
    if (p->per_rev && (p->spindle_dir == 0 || p->speed <= 0.0)) {
        fail_at(p, line, "a turning spindle (S > 0 and M3/M4) for a feed move in G95 (feed per revolution)");
        return -1;
    }
    return 0;
}

/* G0/G1 to the axis words (machine: G53, machine coordinates). */
static int straight(Parser *p, size_t line, int machine) {
    double end[3], dx, dy, dz;
    int rapid = p->motion == 0;
    GcMove *m;
    if (machine) {
        static const char axes[3] = {'X', 'Y', 'Z'};
        int a;
        if (!p->absolute) {
            fail_at(p, line, "G90 with G53 (machine coordinates are absolute)");
            return -1;
        }
        memcpy(end, p->position, sizeof end);
        for (a = 0; a < 3; a++) {
            if (!has(p, axes[a])) continue;
            if (check_coordinate(p, line, val(p, axes[a])) != 0) return -1;
            end[a] = length_of(p, val(p, axes[a]));
        }
    } else if (target(p, line, end) != 0) {
        return -1;
    }
    if (!rapid && need_feed(p, line) != 0) return -1;
    dx = end[0] - p->position[0], dy = end[1] - p->position[1], dz = end[2] - p->position[2];
    if (dx * dx + dy * dy + dz * dz <= 0.0) return 0;
    m = new_move(p, rapid ? MOVE_RAPID : MOVE_LINE, line);
    if (!m) return -1;
    memcpy(m->end, end, sizeof m->end);
    m->feed = rapid ? 0.0 : current_feed(p);
    memcpy(p->position, end, sizeof end);
    return 0;
}

/* A straight move of a canned cycle or G28 (exact stop on cycle moves); nothing for a zero length. */
static int move_to(Parser *p, size_t line, int kind, const double end[3], int exact) {
    double dx = end[0] - p->position[0], dy = end[1] - p->position[1], dz = end[2] - p->position[2];
    GcMove *m;
    if (dx * dx + dy * dy + dz * dz <= 0.0) return 0;
    m = new_move(p, kind, line);
    if (!m) return -1;
    memcpy(m->end, end, sizeof m->end);
    m->feed = kind == MOVE_RAPID ? 0.0 : current_feed(p);
    if (exact) m->exact_stop = 1;
    memcpy(p->position, end, 3 * sizeof *end);
    return 0;
}

static int arc(Parser *p, size_t line) {
    static const int plane_axes[3][3] = {{0, 1, 2}, {2, 0, 1}, {1, 2, 0}};
    static const char centre_words[3][2] = {{'I', 'J'}, {'K', 'I'}, {'J', 'K'}};
    int plane = p->plane == 17 ? 0 : p->plane == 18 ? 1 : 2;
    int ia = plane_axes[plane][0], ib = plane_axes[plane][1], in = plane_axes[plane][2];
    const char *cw = centre_words[plane];
    double end[3], start[3], sa, sb, ea, eb, ca, cb, r0, r1, theta0, theta1, sweep;
    int clockwise = p->motion == 20, has_ijk;
    const char *ijk = "IJK";
    int k;
    GcMove *m;
    if (need_feed(p, line) != 0) return -1;
    if (!has(p, 'X') && !has(p, 'Y') && !has(p, 'Z') && !has(p, 'R') && !has(p, 'I') && !has(p, 'J') &&
        !has(p, 'K')) {
        fail_at(p, line, "an end point or a centre with G2/G3");
        return -1;
    }
    if (target(p, line, end) != 0) return -1;
    memcpy(start, p->position, sizeof start);
    for (k = 0; k < 3; k++) {
        if (has(p, ijk[k]) && ijk[k] != cw[0] && ijk[k] != cw[1]) {
            fail_at(p, line, "the centre words %c, %c in the G%d plane, got %c", cw[0], cw[1], p->plane, ijk[k]);
            return -1;
        }
    }
    has_ijk = has(p, cw[0]) || has(p, cw[1]);
    sa = start[ia], sb = start[ib], ea = end[ia], eb = end[ib];
    if (has_ijk && has(p, 'R')) {
        fail_at(p, line, "either the centre (I, J, K) or the radius R, not both");
        return -1;
    }
    if (!has_ijk && !has(p, 'R')) {
        fail_at(p, line, "the arc centre (%c, %c) or the radius R with G%d", cw[0], cw[1], p->motion / 10);
        return -1;
    }
    if (has_ijk) {
        double offs[2];
        for (k = 0; k < 2; k++) {
            double value = has(p, cw[k]) ? val(p, cw[k]) : 0.0;
            if (check_coordinate(p, line, value) != 0) return -1;
            offs[k] = length_of(p, value);
        }
        ca = sa + offs[0], cb = sb + offs[1];
    } else {
        double r = val(p, 'R'), radius, da, db, chord, half, h2, h, sign;
        int left;
        if (check_coordinate(p, line, r) != 0) return -1;
        radius = length_of(p, fabs(r));
        da = ea - sa, db = eb - sb;
        chord = sqrt(da * da + db * db);
        if (chord <= 0.0) {
            fail_at(p, line, "an end point different from the start with R (a full circle needs I, J, K)");
            return -1;
        }
        if (radius <= 0.0) {
            fail_at(p, line, "a radius R other than 0");
            return -1;
        }
        half = 0.5 * chord;
        if (half > radius * (1.0 + ARC_RADIUS_RELATIVE) + ARC_RADIUS_TOLERANCE) {
            fail_at(p, line, "a radius R of at least half the distance to the end point (%.6g)", half / unit_factor(p));
            return -1;
        }
        h2 = radius * radius - half * half;
        h = h2 > 0.0 ? sqrt(h2) : 0.0;
        left = (!clockwise) == (r > 0);
        sign = left ? 1.0 : -1.0;
        ca = sa + 0.5 * da - sign * h * db / chord;
        cb = sb + 0.5 * db + sign * h * da / chord;
    }
    r0 = sqrt((sa - ca) * (sa - ca) + (sb - cb) * (sb - cb));
    r1 = sqrt((ea - ca) * (ea - ca) + (eb - cb) * (eb - cb));
    if (r0 <= 0.0) {
        fail_at(p, line, "an arc centre away from the start point");
        return -1;
    }
    if (fabs(r1 - r0) > ARC_RADIUS_TOLERANCE + ARC_RADIUS_RELATIVE * r0) {
        fail_at(p, line, "the end point on the arc: its distance from the centre is %.6g, the start's %.6g",
                r1 / unit_factor(p), r0 / unit_factor(p));
        return -1;
    }
    theta0 = atan2(sb - cb, sa - ca);
    theta1 = atan2(eb - cb, ea - ca);
    sweep = theta1 - theta0;
    if (clockwise) {
        if (sweep >= 0.0) sweep -= 2.0 * PI;
    } else {
        if (sweep <= 0.0) sweep += 2.0 * PI;
    }
    m = new_move(p, MOVE_ARC, line);
    if (!m) return -1;
    memcpy(m->end, end, sizeof m->end);
    m->feed = current_feed(p);
    m->center[ia] = ca, m->center[ib] = cb, m->center[in] = start[in];
    m->axes[0] = ia, m->axes[1] = ib, m->axes[2] = in;
    m->theta0 = theta0, m->sweep = sweep, m->r0 = r0, m->r1 = r1;
    m->height = end[in] - start[in];
    memcpy(p->position, end, sizeof end);
    return 0;
}

static int set_feed_and_speed(Parser *p, size_t line) {
    if (has(p, 'F')) {
        double f = val(p, 'F');
        if (!(f > 0.0) || f > MAX_FEED_WORD) {
            fail_at(p, line, "a feed F > 0 and at most %g, got F%.*s", MAX_FEED_WORD, slot(p, 'F')->text_length,
                    slot(p, 'F')->text);
            return -1;
        }
        if (p->per_rev)
            p->feed_rev = length_of(p, f);
        else
            p->feed = length_of(p, f) / 60.0;
    }
    if (has(p, 'S')) {
        double s = val(p, 'S');
        if (s < 0.0 || s > MAX_SPEED_WORD) {
            fail_at(p, line, "a spindle speed S of 0 to %g rpm, got S%.*s", MAX_SPEED_WORD, slot(p, 'S')->text_length,
                    slot(p, 'S')->text);
            return -1;
        }
        p->speed = s;
    }
    if (p->m[M_SPINDLE] >= 0 && p->m[M_SPINDLE] != 19)
        p->spindle_dir = p->m[M_SPINDLE] == 3 ? 1 : p->m[M_SPINDLE] == 4 ? -1 : 0;
    return 0;
}

/* Words of one line into slots and G/M groups; -1 on error. */
static int classify(Parser *p, size_t line) {
    int k;
    memset(p->slots, 0, sizeof p->slots);
    for (k = 0; k < G_GROUPS; k++) p->g[k] = -1;
    for (k = 0; k < M_GROUPS; k++) p->m[k] = -1;
    for (k = 0; k < p->n_words; k++) {
        const Word *w = &p->words[k];
        if (w->letter == 'G') {
            int group = 0, code = g_code(p, line, w, &group);
            if (code < 0) return -1;
            if (p->g[group] >= 0 && group != G_CANCEL) {
                fail_at(p, line, "one G code of the %s group per line, got G%g and G%.*s", G_GROUP_NAMES[group],
                        (double)p->g[group] / 10.0, w->text_length, w->text);
                return -1;
            }
            p->g[group] = code;
        } else if (w->letter == 'M') {
            double v = w->value;
            int code = -1, group = 0;
            size_t j;
            for (j = 0; j < sizeof M_CODES / sizeof M_CODES[0]; j++)
                if (v == (double)M_CODES[j][0]) code = M_CODES[j][0], group = M_CODES[j][1];
            if (code < 0) {
                fail_at(p, line, "a supported M code (%s), got M%.*s", M_LIST, w->text_length, w->text);
                return -1;
            }
            if (p->m[group] >= 0) {
                fail_at(p, line, "one M code of the %s group per line, got M%d and M%.*s", M_GROUP_NAMES[group],
                        p->m[group], w->text_length, w->text);
                return -1;
            }
            p->m[group] = code;
        } else if (w->letter == 'N') {
            int any = 0, j;
            for (j = 0; j < 26; j++) any |= p->slots[j].present;
            for (j = 0; j < G_GROUPS; j++) any |= p->g[j] >= 0 && j != G_NURBS_END; /* G5.3 N..: translator's */
            for (j = 0; j < M_GROUPS; j++) any |= p->m[j] >= 0;
            if (any) {
                fail_at(p, line, "the line number N first in the line");
                return -1;
            }
            if (w->value < 0 || w->value != floor(w->value) || w->value > 2147483647.0) {
                fail_at(p, line, "a whole line number after N, got N%.*s", w->text_length, w->text);
                return -1;
            }
            slot(p, 'N')->present = 1;
            slot(p, 'N')->value = w->value;
        } else if (w->letter == 'O') {
            fail_at(p, line, "a program number O alone in its line (a comment may follow)");
            return -1;
        } else {
            Slot *s = slot(p, w->letter);
            if (s->present) {
                fail_at(p, line, "one %c word per line", w->letter);
                return -1;
            }
            s->present = 1, s->value = w->value, s->text = w->text, s->text_length = w->text_length;
        }
    }
    return 0;
}

/* The next line after `line` that has words or is a tape mark (0 at the end); its words are tokenized. */
static int next_block_line(Parser *p, size_t line, size_t *next, int *has_words) {
    size_t k = line + 1;
    *has_words = 0;
    while (k <= p->n_lines) {
        if (p->line_length[k - 1] > MAX_LINE_LENGTH) {
            fail_at(p, k, "a line of at most %d characters", MAX_LINE_LENGTH);
            return -1;
        }
        if (is_tape_mark(p, k)) break;
        p->n_words = 0;
        if (!is_skipped(p, k) && tokenize(p, k) != 0) return -1;
        if (p->n_words) {
            *has_words = 1;
            break;
        }
        k++;
    }
    *next = k;
    return 0;
}

static int grow_curve(Parser *p, GcCurve *c, size_t *cap, size_t need) {
    if (need > *cap) {
        size_t n = *cap ? 2 * *cap : 64;
        double *pts, *w, *kn;
        while (n < need) n *= 2;
        pts = realloc(c->points, 3 * n * sizeof *pts);
        if (pts) c->points = pts;
        w = realloc(c->weights, n * sizeof *w);
        if (w) c->weights = w;
        kn = realloc(c->knots, (n + MAX_DEGREE + 2) * sizeof *kn);
        if (kn) c->knots = kn;
        if (!pts || !w || !kn) {
            snprintf(p->error, p->error_size, "%s: out of memory for %zu control points", p->file, n);
            return -1;
        }
        *cap = n;
    }
    return 0;
}

/* Stores a NURBS curve (taking its arrays; freed here on failure) and its moves, split at inner knots of
 * multiplicity >= the degree. */
static int emit_curve(Parser *p, GcCurve *curve, size_t first_line, size_t end_line) {
    GcProgram *g = p->program;
    int index, degree = curve->degree;
    size_t n_points = (size_t)curve->n_points, j, n_breaks = 0, b;
    double *breaks, start[3], off[3];
    const double *kn, *last_point;
    if (g->n_curves == g->cap_curves) {
        size_t c = g->cap_curves ? 2 * g->cap_curves : 8;
        GcCurve *cs = realloc(g->curves, c * sizeof *cs);
        if (!cs) {
            snprintf(p->error, p->error_size, "%s: out of memory for %zu curves", p->file, c);
            free(curve->points), free(curve->weights), free(curve->knots);
            return -1;
        }
        g->curves = cs;
        g->cap_curves = c;
    }
    index = (int)g->n_curves;
    g->curves[g->n_curves++] = *curve;
    memset(curve, 0, sizeof *curve);
    kn = g->curves[index].knots;
    last_point = g->curves[index].points + 3 * (n_points - 1);
    breaks = malloc((n_points + 2) * sizeof *breaks);
    if (!breaks) {
        snprintf(p->error, p->error_size, "%s: out of memory", p->file);
        return -1;
    }
    breaks[n_breaks++] = kn[degree];
    j = (size_t)degree + 1;
    while (j < n_points) {
        size_t m = 1;
        while (j + m < n_points && kn[j + m] == kn[j]) m++;
        if (m >= (size_t)degree) breaks[n_breaks++] = kn[j];
        j += m;
    }
    breaks[n_breaks++] = kn[n_points];
    memcpy(start, p->position, sizeof start);
    total_offset(p, off);
    for (b = 0; b + 1 < n_breaks; b++) {
        GcMove *mv = new_move(p, MOVE_NURBS, first_line);
        if (!mv) {
            free(breaks);
            return -1;
        }
        memcpy(mv->start, start, sizeof mv->start);
        memcpy(mv->end, last_point, sizeof mv->end);
        memcpy(mv->offset, off, sizeof mv->offset);
        mv->feed = current_feed(p);
        mv->curve = index;
        mv->u0 = breaks[b];
        mv->u1 = breaks[b + 1];
        memcpy(p->position, last_point, sizeof p->position);
    }
    free(breaks);
    p->program->final_line = (int)end_line;
    return 0;
}

static int nurbs(Parser *p, size_t first_line, size_t *last_line) {
    GcCurve curve;
    size_t cap = 0, line = first_line, end_line, n_knots = 0, n_points, j;
    int degree = 3, trailing = 0, k;
    double previous[3];
    double off[3];
    memset(&curve, 0, sizeof curve);
    total_offset(p, off);
    if (!p->absolute) {
        fail_at(p, line, "G90 (absolute coordinates) for a NURBS block");
        return -1;
    }
    if (has(p, 'I') || has(p, 'J')) {
        fail_at(p, line, "K, X, Y, Z, R, P, F in a G6.2 line, got %c", has(p, 'I') ? 'I' : 'J');
        return -1;
    }
    if (has(p, 'L')) {
        fail_at(p, line, "K, X, Y, Z, R, P, F in a G6.2 line, got L");
        return -1;
    }
    if (!has(p, 'K')) {
        fail_at(p, line, "a knot K in the G6.2 line");
        return -1;
    }
    if (!has(p, 'X') && !has(p, 'Y') && !has(p, 'Z') && !has(p, 'R')) {
        fail_at(p, line, "the first control point (X, Y, Z, R) in the G6.2 line");
        return -1;
    }
    if (has(p, 'P')) {
        double pv = val(p, 'P');
        if (pv != 2.0 && pv != 3.0 && pv != 4.0 && pv != 5.0 && pv != 6.0) {
            fail_at(p, line, "an order P (degree + 1) of 2 to %d, got P%.*s", MAX_DEGREE + 1,
                    slot(p, 'P')->text_length, slot(p, 'P')->text);
            return -1;
        }
        degree = (int)pv - 1;
    }
    if (set_feed_and_speed(p, line) != 0) return -1;
    if (p->g[G_PLANE] >= 0 || p->g[G_UNITS] >= 0 || p->g[G_DISTANCE] >= 0 || p->g[G_OFFSET] >= 0) {
        fail_at(p, line, "no other G code in the G6.2 line");
        return -1;
    }
    if (p->m[M_END] >= 0) {
        fail_at(p, line, "M2/M30 after the NURBS block, not in its first line");
        return -1;
    }
    if (need_feed(p, line) != 0) return -1;
    p->motion = -1;
    curve.degree = degree;
    curve.line = (int)first_line;
    memcpy(previous, p->position, sizeof previous);
    for (;;) {
        double kv;
        int has_point;
        size_t next;
        int more;
        if (line != first_line) {
            static const char allowed[] = "KXYZRN";
            for (k = 0; k < 26; k++) {
                if (p->slots[k].present && !strchr(allowed, 'A' + k)) {
                    fail_at(p, line, "K, X, Y, Z, R in a NURBS block (started in line %zu), got %c", first_line,
                            'A' + k);
                    goto error;
                }
            }
        }
        kv = val(p, 'K');
        if (fabs(kv) > MAX_COORDINATE) {
            fail_at(p, line, "a knot of magnitude at most %g", MAX_COORDINATE);
            goto error;
        }
        has_point = has(p, 'X') || has(p, 'Y') || has(p, 'Z') || has(p, 'R');
        if (has_point) {
            double pt[3], w;
            int a;
            if (trailing) {
                fail_at(p, line, "knot-only lines (K) after the last control point of the NURBS block started in "
                                 "line %zu", first_line);
                goto error;
            }
            if (curve.n_points >= MAX_NURBS_POINTS) {
                fail_at(p, line, "at most %d control points in a NURBS block", MAX_NURBS_POINTS);
                goto error;
            }
            if (control_point(p, line, off, previous, pt) != 0) goto error;
            w = has(p, 'R') ? val(p, 'R') : 1.0;
            if (!(w > 0.0) || w > MAX_COORDINATE) {
                fail_at(p, line, "a weight R > 0 (and at most %g), got R%.*s", MAX_COORDINATE,
                        slot(p, 'R')->text_length, slot(p, 'R')->text);
                goto error;
            }
            if (curve.n_points == 0) {
                double e[3], d;
                for (a = 0; a < 3; a++) e[a] = pt[a] - p->position[a];
                d = sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2]);
                if (d > START_POINT_TOLERANCE) {
                    fail_at(p, line, "the first control point at the current position (%.6g, %.6g, %.6g)",
                            (p->position[0] - off[0]) / unit_factor(p), (p->position[1] - off[1]) / unit_factor(p),
                            (p->position[2] - off[2]) / unit_factor(p));
                    goto error;
                }
                memcpy(pt, p->position, sizeof pt);
            }
            if (grow_curve(p, &curve, &cap, (size_t)curve.n_points + 1) != 0) goto error;
            memcpy(curve.points + 3 * (size_t)curve.n_points, pt, sizeof pt);
            curve.weights[curve.n_points] = w;
            curve.n_points++;
            memcpy(previous, pt, sizeof pt);
        } else {
            trailing++;
            if (trailing > MAX_DEGREE + 1) {
                fail_at(p, line, "degree + 1 = %d knot-only lines (K) closing the NURBS block started in line %zu",
                        degree + 1, first_line);
                goto error;
            }
        }
        if (n_knots && kv < curve.knots[n_knots - 1]) {
            fail_at(p, line, "non-decreasing knots, got K%.*s after %.15g", slot(p, 'K')->text_length,
                    slot(p, 'K')->text, curve.knots[n_knots - 1]);
            goto error;
        }
        if (grow_curve(p, &curve, &cap, (size_t)curve.n_points + 1) != 0) goto error;
        curve.knots[n_knots++] = kv;
        if (next_block_line(p, line, &next, &more) != 0) goto error;
        if (more) {
            more = 0;
            for (k = 0; k < p->n_words; k++) more |= p->words[k].letter == 'K';
        }
        if (!more) {
            end_line = line;
            break;
        }
        /* the continuation line's words: letters at most once */
        memset(p->slots, 0, sizeof p->slots);
        for (k = 0; k < p->n_words; k++) {
            Slot *s = slot(p, p->words[k].letter);
            if (s->present) {
                fail_at(p, next, "one %c word per line", p->words[k].letter);
                goto error;
            }
            s->present = 1, s->value = p->words[k].value, s->text = p->words[k].text;
            s->text_length = p->words[k].text_length;
        }
        line = next;
    }
    n_points = (size_t)curve.n_points;
    if (n_points < (size_t)degree + 1) {
        fail_at(p, end_line, "at least degree + 1 = %d control points in the NURBS block started in line %zu, got %zu",
                degree + 1, first_line, n_points);
        goto error;
    }
    if (trailing != degree + 1) {
        fail_at(p, end_line, "degree + 1 = %d knot-only lines (K) closing the NURBS block started in line %zu, got %d",
                degree + 1, first_line, trailing);
        goto error;
    }
    for (j = 1; j <= (size_t)degree; j++) {
        if (curve.knots[j] != curve.knots[0] || curve.knots[n_knots - 1 - j] != curve.knots[n_knots - 1]) {
            fail_at(p, first_line, "a clamped knot vector (the first and the last %d knots equal) in the NURBS block "
                                   "started here", degree + 1);
            goto error;
        }
    }
    if (!(curve.knots[n_knots - 1] > curve.knots[0])) {
        fail_at(p, first_line, "a last knot greater than the first in the NURBS block started here");
        goto error;
    }
    if (curve.knots[degree + 1] == curve.knots[degree] || curve.knots[n_points] == curve.knots[n_points - 1]) {
        fail_at(p, first_line, "exactly %d equal knots at each end of the NURBS block started here", degree + 1);
        goto error;
    }
    {
        int multiplicity = 1;
        for (j = (size_t)degree + 2; j < n_points; j++) {
            multiplicity = curve.knots[j] == curve.knots[j - 1] ? multiplicity + 1 : 1;
            if (multiplicity > degree) {
                fail_at(p, first_line, "inner knots of multiplicity at most the degree %d in the NURBS block started "
                                       "here (knot %.15g)", degree, curve.knots[j]);
                goto error;
            }
        }
    }
    if (emit_curve(p, &curve, first_line, end_line) != 0) return -1;
    *last_line = end_line;
    return 0;
error:
    free(curve.points);
    free(curve.weights);
    free(curve.knots);
    return -1;
}

static int whole(double v, double max) { return v >= 0.0 && v == floor(v) && v <= max; }

static const GcTool *find_tool(const Parser *p, long number) {
    size_t k;
    for (k = 0; k < p->n_tools; k++)
        if (p->tools[k].number == number) return &p->tools[k];
    return NULL;
}

/* A T, H or D word as a tool number; -1 (reported) if not whole. */
static long tool_number(Parser *p, size_t line, char letter) {
    const Slot *s = slot(p, letter);
    if (!whole(s->value, MAX_PROGRAM_NUMBER)) {
        fail_at(p, line, "a whole tool number after %c, got %c%.*s", letter, letter, s->text_length, s->text);
        return -1;
    }
    return (long)s->value;
}

/* The program number of an O line (the only word of its line); -1 reported. */
static long program_number(Parser *p, size_t line) {
    const Word *w = &p->words[0];
    if (p->dialect == DIALECT_LINUXCNC) {
        fail_at(p, line, "G-code words (LinuxCNC's O-word subroutines and control flow are not supported)");
        return -1;
    }
    if (p->n_words > 1) {
        fail_at(p, line, "a program number O alone in its line (a comment may follow)");
        return -1;
    }
    if (!whole(w->value, MAX_PROGRAM_NUMBER)) {
        fail_at(p, line, "a whole program number of 0 to %d after O, got O%.*s", MAX_PROGRAM_NUMBER, w->text_length,
                w->text);
        return -1;
    }
    return (long)w->value;
}

static int compensation(Parser *p, size_t line, int code) {
    long d;
    double radius = 0.0;
    if (code == 400) {
        if (has(p, 'D')) {
            fail_at(p, line, "no D with G40 (it cancels the cutter radius compensation)");
            return -1;
        }
        p->comp = COMP_OFF, p->comp_radius = 0.0;
        return 0;
    }
    if (p->plane != 17) {
        fail_at(p, line, "G17 (the XY plane) for cutter radius compensation G%d, got G%d", code / 10, p->plane);
        return -1;
    }
    d = p->tool;
    if (has(p, 'D') && (d = tool_number(p, line, 'D')) < 0) return -1;
    if (d != 0) {
        const GcTool *tool = find_tool(p, d);
        if (!tool) {
            char shown[64];
            if (has(p, 'D'))
                snprintf(shown, sizeof shown, "D%.*s", slot(p, 'D')->text_length, slot(p, 'D')->text);
            else
                snprintf(shown, sizeof shown, "G%d (the active tool %ld)", code / 10, d);
            if (p->n_tools)
                fail_at(p, line, "a tool of the tool table for %s (the table has no tool %ld)", shown, d);
            else
                fail_at(p, line, "a tool of the tool table for %s (the tool table is empty: the cutter radius is "
                                 "unknown)", shown);
            return -1;
        }
        radius = 0.5 * tool->diameter;
    } else if (!has(p, 'D')) {
        fail_at(p, line, "D (a tool of the tool table: its radius) with G%d", code / 10);
        return -1;
    }
    p->comp = code == 410 ? COMP_LEFT : COMP_RIGHT;
    p->comp_radius = radius;
    return 0;
}

static int g10(Parser *p, size_t line, int motion_g) {
    static const char axes[3] = {'X', 'Y', 'Z'};
    double pv;
    int a, index;
    if (!has(p, 'L') || val(p, 'L') != 2.0) {
        fail_at(p, line, "L2 with G10 (set a work offset)");
        return -1;
    }
    pv = has(p, 'P') ? val(p, 'P') : 0.0;
    if (!has(p, 'P') || !(pv == 1.0 || pv == 2.0 || pv == 3.0 || pv == 4.0 || pv == 5.0 || pv == 6.0)) {
        fail_at(p, line, "P1 to P6 with G10 L2 (the work offset G54 to G59)");
        return -1;
    }
    if (motion_g >= 0) {
        fail_at(p, line, "no motion G code in a G10 line");
        return -1;
    }
    for (a = 0; a < 4; a++) {
        if (has(p, "IJKR"[a])) {
            fail_at(p, line, "only X, Y, Z with G10 L2, got %c", "IJKR"[a]);
            return -1;
        }
    }
    index = (int)pv - 1;
    for (a = 0; a < 3; a++) {
        if (has(p, axes[a])) {
            double value = val(p, axes[a]);
            if (check_coordinate(p, line, value) != 0) return -1;
            p->offsets[index][a] = length_of(p, value);
        }
    }
    return 0;
}

/* G4/G82 dwell in seconds (Fanuc's P without a decimal point: milliseconds); -1 reported. */
static int dwell_seconds(Parser *p, size_t line, char letter, double *seconds) {
    const Slot *s = slot(p, letter);
    if (s->value < 0.0 || s->value > MAX_COORDINATE) {
        fail_at(p, line, "a dwell %c of 0 to %g, got %c%.*s", letter, MAX_COORDINATE, letter, s->text_length, s->text);
        return -1;
    }
    *seconds = s->value;
    if (letter == 'P' && p->dialect == DIALECT_FANUC && !memchr(s->text, '.', (size_t)s->text_length))
        *seconds = s->value / 1000.0;
    return 0;
}

static int dwell(Parser *p, size_t line, double seconds) {
    GcMove *m;
    if (seconds <= 0.0) return 0;
    if (p->program->n_moves) p->program->moves[p->program->n_moves - 1].exact_stop = 1;
    m = new_move(p, MOVE_DWELL, line);
    if (!m) return -1;
    memcpy(m->end, p->position, sizeof m->end);
    m->dwell = seconds;
    m->exact_stop = 1;
    return 0;
}

static int dwell_line(Parser *p, size_t line, int motion_g) {
    char letter;
    double seconds;
    if (motion_g >= 0) {
        fail_at(p, line, "no motion G code in a G4 line, got G%g", (double)motion_g / 10.0);
        return -1;
    }
    if (p->dialect == DIALECT_FANUC && has(p, 'X')) {
        if (has(p, 'P')) {
            fail_at(p, line, "either P or X with G4 (the dwell), not both");
            return -1;
        }
        letter = 'X';
    } else if (has(p, 'P')) {
        letter = 'P';
    } else {
        fail_at(p, line, "P (the dwell time) with G4%s", p->dialect == DIALECT_FANUC ? " (or X, seconds)" : "");
        return -1;
    }
    if (has(p, 'Y') || has(p, 'Z') || (letter == 'P' && has(p, 'X'))) {
        fail_at(p, line, "no axis word in a G4 line, got %c", has(p, 'Y') ? 'Y' : has(p, 'Z') ? 'Z' : 'X');
        return -1;
    }
    if (dwell_seconds(p, line, letter, &seconds) != 0) return -1;
    return dwell(p, line, seconds);
}

/* G28: rapid through the intermediate point (the axis words) to the home position of those axes. */
static int home_return(Parser *p, size_t line, int motion_g) {
    static const char axes[3] = {'X', 'Y', 'Z'};
    double end[3];
    int a, any = 0;
    if (motion_g >= 0) {
        fail_at(p, line, "no motion G code in a G28 line, got G%g", (double)motion_g / 10.0);
        return -1;
    }
    for (a = 0; a < 4; a++) {
        if (has(p, "IJKR"[a])) {
            fail_at(p, line, "only X, Y, Z with G28, got %c", "IJKR"[a]);
            return -1;
        }
    }
    for (a = 0; a < 3; a++) any |= has(p, axes[a]);
    if (!any) {
        if (p->dialect == DIALECT_FANUC) {
            fail_at(p, line, "the axes to return (X, Y, Z: the intermediate point) with G28");
            return -1;
        }
        memcpy(end, p->home, sizeof end);
    } else {
        double middle[3];
        if (target(p, line, middle) != 0) return -1;
        if (move_to(p, line, MOVE_RAPID, middle, 0) != 0) return -1;
        memcpy(end, p->position, sizeof end);
        for (a = 0; a < 3; a++)
            if (has(p, axes[a])) end[a] = p->home[a];
    }
    return move_to(p, line, MOVE_RAPID, end, 0);
}

/* G73/G81/G82/G83 expanded to moves as a Fanuc control runs them (G17 only). */
static int cycle(Parser *p, size_t line, int new_cycle) {
    int code = p->motion, a;
    long repeats = 1, rep;
    char repeat_letter = p->dialect == DIALECT_FANUC ? 'K' : 'L', other = repeat_letter == 'K' ? 'L' : 'K';
    double off[3], old_z, initial, r, bottom, clear;
    if (p->plane != 17) {
        fail_at(p, line, "G17 (the XY plane) for the canned cycle G%d, got G%d", code / 10, p->plane);
        return -1;
    }
    if (p->comp != COMP_OFF) {
        fail_at(p, line, "G40 (no cutter radius compensation) before the canned cycle G%d", code / 10);
        return -1;
    }
    if (has(p, 'I') || has(p, 'J')) {
        fail_at(p, line, "no %c in a canned cycle", has(p, 'I') ? 'I' : 'J');
        return -1;
    }
    if (has(p, 'R')) {
        if (check_coordinate(p, line, val(p, 'R')) != 0) return -1;
        p->cycle_r = val(p, 'R'), p->has_cycle_r = 1;
    }
    if (has(p, 'Z')) {
        if (check_coordinate(p, line, val(p, 'Z')) != 0) return -1;
        p->cycle_z = val(p, 'Z'), p->has_cycle_z = 1;
    }
    if (has(p, 'Q')) {
        double q = val(p, 'Q');
        if (!(q > 0.0) || q > MAX_COORDINATE) {
            fail_at(p, line, "a peck depth Q > 0 (and at most %g), got Q%.*s", MAX_COORDINATE,
                    slot(p, 'Q')->text_length, slot(p, 'Q')->text);
            return -1;
        }
        p->cycle_q = length_of(p, q);
    }
    if (has(p, 'P') && dwell_seconds(p, line, 'P', &p->cycle_p) != 0) return -1;
    if (!p->has_cycle_r) {
        fail_at(p, line, "R (the retract plane) with G%d", code / 10);
        return -1;
    }
    if (!p->has_cycle_z) {
        fail_at(p, line, "Z (the hole bottom) with G%d", code / 10);
        return -1;
    }
    if ((code == 730 || code == 830) && !(p->cycle_q > 0.0)) {
        fail_at(p, line, "Q (the peck depth) with G%d", code / 10);
        return -1;
    }
    if (need_feed(p, line) != 0) return -1;
    if (has(p, other)) {
        fail_at(p, line, "%c (the repeat count) in a canned cycle of this dialect, got %c", repeat_letter, other);
        return -1;
    }
    if (has(p, repeat_letter)) {
        const Slot *s = slot(p, repeat_letter);
        if (!whole(s->value, MAX_REPEATS)) {
            fail_at(p, line, "a whole repeat count %c of 0 to %d, got %c%.*s", repeat_letter, MAX_REPEATS,
                    repeat_letter, s->text_length, s->text);
            return -1;
        }
        repeats = (long)s->value;
    }
    total_offset(p, off);
    old_z = p->position[2];
    if (new_cycle || p->dialect != DIALECT_FANUC) p->cycle_initial = old_z;
    initial = p->cycle_initial;
    if (p->absolute) {
        r = length_of(p, p->cycle_r) + off[2];
        bottom = length_of(p, p->cycle_z) + off[2];
    } else {
        r = initial + length_of(p, p->cycle_r);
        bottom = r + length_of(p, p->cycle_z);
    }
    if (bottom > r) {
        fail_at(p, line, "the hole bottom Z below the retract plane R in G%d", code / 10);
        return -1;
    }
    if (p->retract_r)
        clear = r;
    else
        clear = (p->dialect == DIALECT_FANUC || initial > r) ? initial : r;
    for (rep = 0; rep < repeats; rep++) {
        double hole[3], to[3];
        if (rep == 0 && p->dialect != DIALECT_FANUC && p->position[2] < r) {
            to[0] = p->position[0], to[1] = p->position[1], to[2] = r;
            if (move_to(p, line, MOVE_RAPID, to, 1) != 0) return -1;
        }
        memcpy(hole, p->position, sizeof hole);
        for (a = 0; a < 2; a++) {
            if (has(p, "XY"[a])) {
                double value = length_of(p, val(p, "XY"[a]));
                hole[a] = p->absolute ? value + off[a] : p->position[a] + value;
            }
        }
        if (move_to(p, line, MOVE_RAPID, hole, 1) != 0) return -1;
        to[0] = hole[0], to[1] = hole[1], to[2] = r;
        if (move_to(p, line, MOVE_RAPID, to, 1) != 0) return -1;
        if (code == 810 || code == 820) {
            to[2] = bottom;
            if (move_to(p, line, MOVE_LINE, to, 1) != 0) return -1;
            if (code == 820 && dwell(p, line, p->cycle_p) != 0) return -1;
        } else {
            double depth = r;
            while (depth > bottom) {
                double next;
                if (depth < r && code == 830) {
                    to[2] = depth + PECK_CLEARANCE;
                    if (move_to(p, line, MOVE_RAPID, to, 1) != 0) return -1;
                }
                next = depth - p->cycle_q;
                if (next < bottom) next = bottom;
                to[2] = next;
                if (move_to(p, line, MOVE_LINE, to, 1) != 0) return -1;
                depth = next;
                if (depth > bottom) {
                    to[2] = code == 830 ? r : depth + PECK_CLEARANCE;
                    if (move_to(p, line, MOVE_RAPID, to, 1) != 0) return -1;
                }
            }
        }
        to[2] = clear;
        if (move_to(p, line, MOVE_RAPID, to, 1) != 0) return -1;
    }
    return 0;
}

/* M98/M99: *next is the line to run next. */
static int subprogram(Parser *p, size_t line, int code, size_t *next) {
    long target_number, count = 1;
    size_t index, k;
    if (code == 99) {
        Call *call;
        if (!p->depth) {
            note(p, line, "M99", "M99 in the main program: the program ends here (a control would start it again)");
            p->ended = (int)line;
            return 0;
        }
        call = &p->stack[p->depth - 1];
        call->remaining--;
        if (call->remaining > 0) {
            *next = p->sections[call->section].o_line + 1;
            return 0;
        }
        *next = call->return_to;
        p->depth--;
        return 0;
    }
    if (!has(p, 'P')) {
        fail_at(p, line, "P (the program number) with M98");
        return -1;
    }
    if (!whole(val(p, 'P'), MAX_PROGRAM_NUMBER)) {
        fail_at(p, line, "a whole program number after P, got P%.*s", slot(p, 'P')->text_length, slot(p, 'P')->text);
        return -1;
    }
    target_number = (long)val(p, 'P');
    if (has(p, 'L')) {
        if (!whole(val(p, 'L'), MAX_REPEATS)) {
            fail_at(p, line, "a whole repeat count L of 0 to %d, got L%.*s", MAX_REPEATS, slot(p, 'L')->text_length,
                    slot(p, 'L')->text);
            return -1;
        }
        count = (long)val(p, 'L');
    } else if (p->dialect == DIALECT_FANUC && target_number > 9999) {
        count = target_number / 10000, target_number = target_number % 10000;
    }
    for (index = 0; index < p->n_sections; index++)
        if (p->sections[index].o_line > 0 && p->sections[index].number == target_number) break;
    if (index == p->n_sections) {
        fail_at(p, line, "a program O%ld in this file for M98 (subprograms are read from the same file)",
                target_number);
        return -1;
    }
    for (k = 0; k < (size_t)p->depth; k++)
        if (p->stack[k].section == index) break;
    if (k < (size_t)p->depth || index == p->main_section) {
        fail_at(p, line, "no recursive call: O%ld is already running", target_number);
        return -1;
    }
    if (p->depth >= MAX_CALL_DEPTH) {
        fail_at(p, line, "subprogram calls nested at most %d deep", MAX_CALL_DEPTH);
        return -1;
    }
    if (count == 0) return 0;
    p->stack[p->depth].section = index;
    p->stack[p->depth].return_to = line + 1;
    p->stack[p->depth].remaining = count;
    p->stack[p->depth].line = line;
    p->depth++;
    *next = p->sections[index].o_line + 1;
    return 0;
}

/* LinuxCNC G5 (cubic) and G5.1 (quadratic) as exact Bezier NURBS in the XY plane (parser.py spline). */
static int spline(Parser *p, size_t line) {
    int code = p->motion, k, a, n_points, all_start = 1;
    const char *name = code == 50 ? "G5" : "G5.1";
    double end[3], start[3], words[4] = {0.0, 0.0, 0.0, 0.0}, pts[4][3];
    int given[4] = {0, 0, 0, 0};
    static const char letters[5] = {'Z', 'K', 'R', 'P', 'Q'};
    GcCurve curve;
    size_t cap = 0;
    if (p->dialect != DIALECT_LINUXCNC) {
        fail_at(p, line, "%s is LinuxCNC's %s spline: set dialect = linuxcnc", name,
                code == 50 ? "cubic" : "quadratic");
        return -1;
    }
    if (p->plane != 17) {
        fail_at(p, line, "G17 (the XY plane) for %s, got G%d", name, p->plane);
        return -1;
    }
    for (k = 0; k < (code == 51 ? 5 : 3); k++) {
        if (has(p, letters[k])) {
            fail_at(p, line, "no %c with %s", letters[k], name);
            return -1;
        }
    }
    if (need_feed(p, line) != 0) return -1;
    if (target(p, line, end) != 0) return -1;
    memcpy(start, p->position, sizeof start);
    for (k = 0; k < 4; k++) {
        char letter = "IJPQ"[k];
        if (!has(p, letter)) continue;
        if (check_coordinate(p, line, val(p, letter)) != 0) return -1;
        words[k] = length_of(p, val(p, letter)), given[k] = 1;
    }
    memcpy(pts[0], start, sizeof start);
    if (code == 50) {
        if (given[0] || given[1]) {
            pts[1][0] = start[0] + words[0], pts[1][1] = start[1] + words[1];
        } else if (p->has_last_pq && p->last_pq_moves == p->program->n_moves) {
            pts[1][0] = start[0] - p->last_pq[0], pts[1][1] = start[1] - p->last_pq[1];
        } else {
            fail_at(p, line, "I, J (the first control point, from the start) with G5 (or a G5 just before)");
            return -1;
        }
        if (!given[2] || !given[3]) {
            fail_at(p, line, "P and Q (the second control point, from the end point) with G5");
            return -1;
        }
        pts[1][2] = start[2];
        pts[2][0] = end[0] + words[2], pts[2][1] = end[1] + words[3], pts[2][2] = start[2];
        memcpy(pts[3], end, sizeof end);
        n_points = 4;
    } else {
        if (!given[0] && !given[1]) {
            fail_at(p, line, "I, J (the control point, from the start) with G5.1");
            return -1;
        }
        pts[1][0] = start[0] + words[0], pts[1][1] = start[1] + words[1], pts[1][2] = start[2];
        memcpy(pts[2], end, sizeof end);
        n_points = 3;
    }
    for (k = 1; k < n_points; k++)
        for (a = 0; a < 3; a++) all_start &= pts[k][a] == start[a];
    if (all_start) {
        fail_at(p, line, "an end point or control points away from the start with %s", name);
        return -1;
    }
    memset(&curve, 0, sizeof curve);
    if (grow_curve(p, &curve, &cap, (size_t)n_points) != 0) {
        free(curve.points), free(curve.weights), free(curve.knots);
        return -1;
    }
    curve.degree = n_points - 1;
    curve.n_points = n_points;
    curve.line = (int)line;
    for (k = 0; k < n_points; k++) {
        memcpy(curve.points + 3 * k, pts[k], sizeof pts[k]);
        curve.weights[k] = 1.0;
        curve.knots[k] = 0.0, curve.knots[n_points + k] = 1.0;
    }
    if (emit_curve(p, &curve, line, line) != 0) return -1;
    p->has_last_pq = code == 50;
    p->last_pq_moves = p->program->n_moves;
    p->last_pq[0] = words[2], p->last_pq[1] = words[3];
    return 0;
}

/* P, L, Q, K: used by a code of the line or the motion mode (after this line's motion code). */
static int word_used(const Parser *p, char letter, int motion_g, int non_modal) {
    int motion = motion_g >= 0 ? motion_g : p->g[G_CYCLE] >= 0 ? -1 : p->motion, cycle;
    int spline = motion == 50 && non_modal != 40 && non_modal != 100 && non_modal != 280 && non_modal != 520;
    cycle = is_cycle(motion) && non_modal != 40 && non_modal != 100 && non_modal != 280 && non_modal != 520;
    if (letter == 'P')
        return non_modal == 40 || non_modal == 100 || p->g[G_PATH] == 640 || p->m[M_SUBPROGRAM] == 98 ||
               (cycle && motion == 820) || spline;
    if (letter == 'L') return non_modal == 100 || p->m[M_SUBPROGRAM] == 98 || cycle;
    if (letter == 'Q') return (cycle && (motion == 730 || motion == 830)) || spline;
    return cycle || (non_modal != 40 && non_modal != 100 && non_modal != 280 && non_modal != 520 &&
                     (motion == 20 || motion == 30));
}

static int g52_nurbs(Parser *p, size_t first_line, size_t *next_line);

/* One line; *next is the line to run next (a NURBS block takes several, M98/M99 jump). */
static int parse_line(Parser *p, size_t line, size_t *next) {
    static const char axes_letters[3] = {'X', 'Y', 'Z'};
    int motion_g, non_modal, has_axes, a;
    *next = line + 1;
    if (p->line_length[line - 1] > MAX_LINE_LENGTH) {
        fail_at(p, line, "a line of at most %d characters", MAX_LINE_LENGTH);
        return -1;
    }
    if (is_tape_mark(p, line) || is_skipped(p, line)) return 0;
    if (tokenize(p, line) != 0) return -1;
    if (!p->n_words) return 0;
    if (p->words[0].letter == 'O') {
        long index;
        if (program_number(p, line) < 0) return -1;
        index = p->section_at ? p->section_at[line - 1] : -1;
        if (index >= 0 && !((size_t)index == p->main_section && !p->depth)) *next = p->sections[index].end;
        return 0;
    }
    if (p->ended) {
        fail_at(p, line, "nothing after the program end (M2/M30 in line %d)", p->ended);
        return -1;
    }
    p->program->final_line = (int)line;
    if (classify(p, line) != 0) return -1;
    p->block = has(p, 'N') ? (int)val(p, 'N') : 0;
    p->program->final_block = p->block;
    p->g9 = p->g[G_G9] >= 0;
    motion_g = p->g[G_MOTION];
    if (motion_g == 62 || motion_g == 52) {
        static const int groups[] = {G_NON_MODAL, G_CYCLE, G_COMP, G_LENGTH, G_PATH, G_FEED, G_RETRACT};
        static const int m_groups[] = {M_TOOL_CHANGE, M_SUBPROGRAM, M_STOP};
        size_t k;
        if (motion_g == 62 && p->dialect != DIALECT_FANUC) {
            fail_at(p, line, "G6.2 is Fanuc's NURBS: set dialect = fanuc (or write the curve as G5.2 ... G5.3)");
            return -1;
        }
        if (motion_g == 52 && p->dialect == DIALECT_FANUC) {
            fail_at(p, line, "G5.2 is LinuxCNC's NURBS: set dialect = linuxcnc (Fanuc's NURBS is G6.2)");
            return -1;
        }
        for (k = 0; k < sizeof groups / sizeof groups[0]; k++) {
            if (p->g[groups[k]] >= 0) {
                fail_at(p, line, "no other G code in the G%g line, got G%g", (double)motion_g / 10.0,
                        (double)p->g[groups[k]] / 10.0);
                return -1;
            }
        }
        for (k = 0; k < sizeof m_groups / sizeof m_groups[0]; k++) {
            if (p->m[m_groups[k]] >= 0) {
                fail_at(p, line, "no M%d in the G%g line", p->m[m_groups[k]], (double)motion_g / 10.0);
                return -1;
            }
        }
        for (k = 0; k < 5; k++) {
            if (has(p, "THDQO"[k])) {
                fail_at(p, line, "no %c word in the G%g line", "THDQO"[k], (double)motion_g / 10.0);
                return -1;
            }
        }
        if (motion_g == 62) {
            size_t last;
            if (nurbs(p, line, &last) != 0) return -1;
            *next = last + 1;
            return 0;
        }
        return g52_nurbs(p, line, next);
    }
    if (p->g[G_NURBS_END] >= 0 && line != p->closing_line) {
        fail_at(p, line, "G5.3 after a G5.2 block (it ends the block started by G5.2)");
        return -1;
    }
    if (p->g[G_UNITS] >= 0) p->inch = p->g[G_UNITS] == 200;
    if (p->g[G_FEED] >= 0) {
        int per_rev = p->g[G_FEED] == 950;
        if (per_rev != p->per_rev) {
            p->per_rev = per_rev;
            p->feed = 0.0, p->feed_rev = 0.0;
        }
    }
    if (set_feed_and_speed(p, line) != 0) return -1;
    if (has(p, 'T')) {
        long tn = tool_number(p, line, 'T');
        if (tn < 0) return -1;
        if (tn != 0 && !find_tool(p, tn)) {
            if (p->n_tools) {
                fail_at(p, line, "a tool of the tool table for T%.*s (the table has no tool %ld)",
                        slot(p, 'T')->text_length, slot(p, 'T')->text, tn);
                return -1;
            }
            note(p, line, "T", "T%.*s: no tool table: the tool geometry stays the model's parameters",
                 slot(p, 'T')->text_length, slot(p, 'T')->text);
        }
        p->pending_tool = (int)tn;
    }
    if (p->m[M_TOOL_CHANGE] >= 0) {
        if (p->pending_tool < 0) {
            fail_at(p, line, "a tool T before M6 (no tool selected)");
            return -1;
        }
        p->tool = p->pending_tool;
        note(p, line, "M6", "M6: the tool change takes no time and no motion here");
    }
    if (p->m[M_COOLANT] >= 0) {
        int c = p->m[M_COOLANT];
        p->coolant = c == 9 ? COOLANT_OFF : (p->coolant | (c == 7 ? COOLANT_MIST : COOLANT_FLOOD));
    }
    if (p->m[M_SPINDLE] == 19) note(p, line, "M19", "M19: spindle orientation not modelled");
    if (p->g[G_PLANE] >= 0) p->plane = p->g[G_PLANE] / 10;
    if (p->g[G_DISTANCE] >= 0) p->absolute = p->g[G_DISTANCE] == 900;
    if (p->g[G_OFFSET] >= 0) {
        if (p->g[G_OFFSET] == 5000) {
            if (p->dialect != DIALECT_SINUMERIK) {
                fail_at(p, line, "G500 is Sinumerik's: set dialect = sinumerik (or use G54-G59)");
                return -1;
            }
            p->active_offset = -1;
        } else {
            p->active_offset = (p->g[G_OFFSET] - 540) / 10;
        }
    }
    if (p->g[G_PATH] >= 0) {
        if (p->g[G_PATH] == 640) {
            double tol = 0.0;
            p->exact_mode = 0;
            if (has(p, 'P')) {
                tol = val(p, 'P');
                if (tol < 0.0 || tol > MAX_COORDINATE) {
                    fail_at(p, line, "a contour tolerance P of 0 to %g, got P%.*s", MAX_COORDINATE,
                            slot(p, 'P')->text_length, slot(p, 'P')->text);
                    return -1;
                }
                tol = length_of(p, tol);
            }
            p->tolerance = tol;
        } else {
            p->exact_mode = 1;
        }
    }
    if (p->g[G_RETRACT] >= 0) p->retract_r = p->g[G_RETRACT] == 990;
    if (p->g[G_COMP] >= 0) {
        if (compensation(p, line, p->g[G_COMP]) != 0) return -1;
    } else if (has(p, 'D')) {
        fail_at(p, line, "D only with G41/G42 (the cutter radius of a tool)");
        return -1;
    }
    if (p->g[G_LENGTH] >= 0) {
        int code = p->g[G_LENGTH];
        if (code == 490) {
            if (has(p, 'H')) {
                fail_at(p, line, "no H with G49 (it cancels the tool length offset)");
                return -1;
            }
            p->length_offset = 0.0;
        } else {
            long h = p->tool;
            double length = 0.0;
            if (has(p, 'H') && (h = tool_number(p, line, 'H')) < 0) return -1;
            if (h != 0) {
                const GcTool *tool = find_tool(p, h);
                if (tool) {
                    length = tool->length;
                } else if (p->n_tools) {
                    if (has(p, 'H'))
                        fail_at(p, line, "a tool of the tool table for H%.*s (the table has no tool %ld)",
                                slot(p, 'H')->text_length, slot(p, 'H')->text, h);
                    else
                        fail_at(p, line, "a tool of the tool table for H%ld (the table has no tool %ld)", h, h);
                    return -1;
                } else {
                    note(p, line, "H", "G%g H%ld: no tool table: the tool length is 0", (double)code / 10.0, h);
                }
            }
            p->length_offset = code == 430 ? length : -length;
        }
    } else if (has(p, 'H')) {
        fail_at(p, line, "H only with G43/G44 (a tool length offset)");
        return -1;
    }
    non_modal = p->g[G_NON_MODAL];
    if (p->g[G_CYCLE] >= 0) {
        if (is_cycle(motion_g)) { /* G80 with G0/G1 is fine: "G0 G17 G40 G49 G80 G90" */
            fail_at(p, line, "either G80 or a canned cycle, got G80 and G%g", (double)motion_g / 10.0);
            return -1;
        }
        p->motion = -1;
        p->has_cycle_r = p->has_cycle_z = 0;
    }
    {
        static const char letters[4] = {'P', 'L', 'Q', 'K'};
        static const char *const messages[4] = {
            "P only with G4, G5, G10, G64, G82, M98 (or with G6.2 or G5.2)",
            "L only with G10, M98 or a canned cycle (repeats) (or with G5.2)",
            "Q only with G73/G83 (the peck depth) or G5", "K only with G2/G3 (or in a NURBS block)"};
        int k;
        for (k = 0; k < 4; k++) {
            if (has(p, letters[k]) && !word_used(p, letters[k], motion_g, non_modal)) {
                fail_at(p, line, "%s", messages[k]);
                return -1;
            }
        }
    }
    has_axes = has(p, 'X') || has(p, 'Y') || has(p, 'Z');
    if (non_modal == 40) {
        if (dwell_line(p, line, motion_g) != 0) return -1;
    } else if (non_modal == 100) {
        if (g10(p, line, motion_g) != 0) return -1;
    } else if (non_modal == 520) {
        if (motion_g >= 0) {
            fail_at(p, line, "no motion G code in a G52 line");
            return -1;
        }
        for (a = 0; a < 3; a++) {
            if (has(p, axes_letters[a])) {
                if (check_coordinate(p, line, val(p, axes_letters[a])) != 0) return -1;
                p->local[a] = length_of(p, val(p, axes_letters[a]));
            }
        }
    } else if (non_modal == 280) {
        if (home_return(p, line, motion_g) != 0) return -1;
    } else {
        int previous = p->motion;
        if (motion_g >= 0) {
            p->motion = motion_g;
            if (is_cycle(previous) && !is_cycle(motion_g)) p->has_cycle_r = p->has_cycle_z = 0;
        }
        if (is_cycle(p->motion)) {
            if (motion_g >= 0 || has_axes || has(p, 'R')) {
                if (non_modal == 530) {
                    fail_at(p, line, "no G53 in a canned cycle");
                    return -1;
                }
                if (cycle(p, line, motion_g >= 0 && !is_cycle(previous)) != 0) return -1;
            }
        } else if ((p->motion == 50 || p->motion == 51) && (has_axes || motion_g >= 0)) {
            if (non_modal == 530) {
                fail_at(p, line, "G53 only with G0 or G1");
                return -1;
            }
            if (spline(p, line) != 0) return -1;
        } else {
            char arc_word = 0;
            for (a = 0; a < 4 && !arc_word; a++)
                if (has(p, "IJKR"[a])) arc_word = "IJKR"[a];
            if (non_modal == 530 && p->motion != 0 && p->motion != 10) {
                fail_at(p, line, "G53 only with G0 or G1");
                return -1;
            }
            if ((p->motion == 20 || p->motion == 30) && (has_axes || motion_g >= 0 || arc_word)) {
                if (arc(p, line) != 0) return -1;
            } else if (has_axes || motion_g >= 0) {
                if (arc_word) {
                    fail_at(p, line, "%c only with G2/G3 (or in a NURBS block)", arc_word);
                    return -1;
                }
                if (p->motion < 0) {
                    fail_at(p, line, "a motion mode G0, G1, G2 or G3 before coordinates");
                    return -1;
                }
                if (has_axes && straight(p, line, non_modal == 530) != 0) return -1;
            } else if (arc_word) {
                fail_at(p, line, "%c only with G2/G3 (or in a NURBS block)", arc_word);
                return -1;
            } else if (non_modal == 530) {
                fail_at(p, line, "X, Y or Z (machine coordinates) with G53");
                return -1;
            }
        }
    }
    if (p->m[M_STOP] >= 0) {
        char key[16];
        snprintf(key, sizeof key, "M%d", p->m[M_STOP]);
        note(p, line, key, "M%d: program stop not modelled (the program runs on)", p->m[M_STOP]);
    }
    if (p->m[M_END] >= 0) p->ended = (int)line;
    if (p->m[M_SUBPROGRAM] >= 0) return subprogram(p, line, p->m[M_SUBPROGRAM], next);
    return 0;
}

/* G5.2 [X Y Z] [P weight] [L order] [K interval], control point lines X Y Z [P] [K], G5.3 (parser.py g52_nurbs). */
static int g52_nurbs(Parser *p, size_t first_line, size_t *next_line) {
    GcCurve curve;
    size_t cap = 0, ln = first_line, n_points, i, cap_intervals = 0;
    int order = 3, k;
    double off[3], *intervals = NULL, t;
    memset(&curve, 0, sizeof curve);
    if (!p->absolute) {
        fail_at(p, ln, "G90 (absolute coordinates) for a NURBS block");
        return -1;
    }
    for (k = 0; k < 4; k++) {
        if (has(p, "IJRQ"[k])) {
            fail_at(p, ln, "X, Y, Z, P, L, K, F in a G5.2 line, got %c", "IJRQ"[k]);
            return -1;
        }
    }
    if (has(p, 'L')) {
        double lv = val(p, 'L');
        if (lv != 2.0 && lv != 3.0 && lv != 4.0 && lv != 5.0 && lv != 6.0) {
            fail_at(p, ln, "an order L (degree + 1) of 2 to %d, got L%.*s", MAX_DEGREE + 1, slot(p, 'L')->text_length,
                    slot(p, 'L')->text);
            return -1;
        }
        order = (int)lv;
    }
    if (set_feed_and_speed(p, ln) != 0) return -1;
    if (p->g[G_PLANE] >= 0 || p->g[G_UNITS] >= 0 || p->g[G_DISTANCE] >= 0 || p->g[G_OFFSET] >= 0) {
        fail_at(p, ln, "no other G code in the G5.2 line");
        return -1;
    }
    if (p->m[M_END] >= 0) {
        fail_at(p, ln, "M2/M30 after the NURBS block, not in its first line");
        return -1;
    }
    if (need_feed(p, ln) != 0) return -1;
    p->motion = -1;
    total_offset(p, off);
    if (grow_curve(p, &curve, &cap, 1) != 0) goto error;
    memcpy(curve.points, p->position, sizeof p->position);
    curve.weights[0] = 1.0;
    curve.n_points = 1;
    for (;;) {
        int has_point = has(p, 'X') || has(p, 'Y') || has(p, 'Z'), more;
        double w = 1.0;
        size_t next;
        if (ln != first_line) {
            for (k = 0; k < 26; k++) {
                if (p->slots[k].present && !strchr("XYZPKN", 'A' + k)) {
                    fail_at(p, ln, "X, Y, Z, P, K in a G5.2 block (started in line %zu), or G5.3 to end it, got %c",
                            first_line, 'A' + k);
                    goto error;
                }
            }
        }
        if (has(p, 'P')) {
            w = val(p, 'P');
            if (!(w > 0.0) || w > MAX_COORDINATE) {
                fail_at(p, ln, "a weight P > 0 (and at most %g), got P%.*s", MAX_COORDINATE, slot(p, 'P')->text_length,
                        slot(p, 'P')->text);
                goto error;
            }
        }
        if (has_point) {
            double pt[3], interval = 1.0;
            const double *prev;
            if ((size_t)curve.n_points >= MAX_NURBS_POINTS) {
                fail_at(p, ln, "at most %d control points in a NURBS block", MAX_NURBS_POINTS);
                goto error;
            }
            prev = curve.points + 3 * (size_t)(curve.n_points - 1);
            if (control_point(p, ln, off, prev, pt) != 0) goto error;
            if (has(p, 'K')) {
                interval = val(p, 'K');
                if (!(interval > 0.0) || interval > MAX_COORDINATE) {
                    fail_at(p, ln, "a knot interval K > 0 (and at most %g), got K%.*s", MAX_COORDINATE,
                            slot(p, 'K')->text_length, slot(p, 'K')->text);
                    goto error;
                }
            }
            if (grow_curve(p, &curve, &cap, (size_t)curve.n_points + 1) != 0) goto error;
            if ((size_t)curve.n_points > cap_intervals) {
                size_t c = cap_intervals ? 2 * cap_intervals : 64;
                double *iv = realloc(intervals, c * sizeof *iv);
                if (!iv) {
                    snprintf(p->error, p->error_size, "%s: out of memory for %zu knot intervals", p->file, c);
                    goto error;
                }
                intervals = iv, cap_intervals = c;
            }
            memcpy(curve.points + 3 * (size_t)curve.n_points, pt, sizeof pt);
            curve.weights[curve.n_points] = w;
            intervals[curve.n_points - 1] = interval;
            curve.n_points++;
        } else if (ln == first_line && !has(p, 'K')) {
            curve.weights[0] = w;
        } else {
            fail_at(p, ln, "X, Y or Z (a control point) in the G5.2 block started in line %zu", first_line);
            goto error;
        }
        if (next_block_line(p, ln, &next, &more) != 0) goto error;
        if (!more) {
            fail_at(p, first_line, "G5.3 to end the NURBS block started here");
            goto error;
        }
        ln = next;
        more = 0;
        for (k = 0; k < p->n_words; k++) more |= p->words[k].letter == 'G';
        if (more) {
            const Word *first = p->words[0].letter == 'N' && p->n_words > 1 ? &p->words[1] : &p->words[0];
            if (first->letter != 'G' || first->value * 10.0 != 53.0) {
                fail_at(p, ln, "G5.3 first to end the G5.2 block started in line %zu (a control point line holds X, Y, "
                               "Z, P, K)", first_line);
                goto error;
            }
            break;
        }
        memset(p->slots, 0, sizeof p->slots);
        for (k = 0; k < p->n_words; k++) {
            Slot *s = slot(p, p->words[k].letter);
            if (s->present) {
                fail_at(p, ln, "one %c word per line", p->words[k].letter);
                goto error;
            }
            s->present = 1, s->value = p->words[k].value, s->text = p->words[k].text;
            s->text_length = p->words[k].text_length;
        }
    }
    n_points = (size_t)curve.n_points;
    if (n_points < (size_t)order) {
        fail_at(p, ln, "at least L = %d control points (the current position and %d more) in the G5.2 block started "
                       "in line %zu, got %zu", order, order - 1, first_line, n_points);
        goto error;
    }
    curve.degree = order - 1;
    curve.line = (int)first_line;
    for (i = 0; i < (size_t)order; i++) curve.knots[i] = 0.0;
    t = 0.0;
    for (i = 0; i + (size_t)order < n_points + 1; i++) {
        t = t + intervals[i];
        curve.knots[(size_t)order + i] = t;
    }
    for (i = 0; i + 1 < (size_t)order; i++) curve.knots[n_points + 1 + i] = t;
    free(intervals);
    if (emit_curve(p, &curve, first_line, ln) != 0) return -1;
    p->program->final_block = p->block;
    p->closing_line = ln; /* the G5.3 line runs next: the words after G5.3 (G1 X.., M30) are executed */
    *next_line = ln;
    return 0;
error:
    free(intervals);
    free(curve.points);
    free(curve.weights);
    free(curve.knots);
    return -1;
}

/* Splits a file with program numbers (O or ':' lines) into sections; the main program is the first section
 * without M99 (or the first section). A file without them is one section. */
static int scan_sections(Parser *p) {
    size_t k, n = p->n_lines, count = 0, i, j;
    int any = 0, has_words = 0;
    Section current;
    for (k = 1; k <= n && !any; k++) {
        const char *s = p->text + p->line_start[k - 1];
        size_t len = p->line_length[k - 1], c = 0;
        while (c < len && (s[c] == ' ' || s[c] == '\t')) c++;
        any = c < len && (s[c] == 'O' || s[c] == 'o' || s[c] == ':');
    }
    p->sections = malloc((any ? n + 1 : 1) * sizeof *p->sections);
    if (!p->sections) {
        snprintf(p->error, p->error_size, "%s: out of memory", p->file);
        return -1;
    }
    p->main_section = 0;
    if (!any) {
        p->sections[0].number = -1, p->sections[0].o_line = 0, p->sections[0].end = n + 1;
        p->sections[0].subprogram = 0;
        p->n_sections = 1;
        return 0;
    }
    p->section_at = malloc(n * sizeof *p->section_at);
    if (!p->section_at) {
        snprintf(p->error, p->error_size, "%s: out of memory", p->file);
        return -1;
    }
    for (k = 0; k < n; k++) p->section_at[k] = -1;
    current.number = -1, current.o_line = 0, current.end = n + 1, current.subprogram = 0;
    for (k = 1; k <= n; k++) {
        int w;
        if (p->line_length[k - 1] > MAX_LINE_LENGTH) {
            fail_at(p, k, "a line of at most %d characters", MAX_LINE_LENGTH);
            return -1;
        }
        if (is_tape_mark(p, k) || is_skipped(p, k)) continue;
        if (tokenize(p, k) != 0) return -1;
        if (!p->n_words) continue;
        if (p->words[0].letter == 'O') {
            long number = program_number(p, k);
            if (number < 0) return -1;
            if (current.o_line > 0 || has_words) {
                current.end = k;
                p->sections[count++] = current;
            }
            current.number = number, current.o_line = k, current.end = n + 1, current.subprogram = 0;
            has_words = 1;
            continue;
        }
        has_words = 1;
        for (w = 0; w < p->n_words; w++)
            if (p->words[w].letter == 'M' && p->words[w].value == 99.0) current.subprogram = 1;
    }
    if (current.o_line > 0 || has_words) p->sections[count++] = current;
    p->n_sections = count;
    for (i = 0; i < count; i++) {
        if (p->sections[i].o_line == 0) continue;
        for (j = 0; j < i; j++) {
            if (p->sections[j].o_line > 0 && p->sections[j].number == p->sections[i].number) {
                fail_at(p, p->sections[i].o_line, "one program O%ld in the file (also in line %zu)",
                        p->sections[i].number, p->sections[j].o_line);
                return -1;
            }
        }
        p->section_at[p->sections[i].o_line - 1] = (long)i;
    }
    for (i = 0; i < count && p->sections[i].subprogram; i++) {
    }
    p->main_section = i < count ? i : 0;
    if (count == 0) {
        p->sections[0].number = -1, p->sections[0].o_line = 0, p->sections[0].end = n + 1;
        p->sections[0].subprogram = 0;
        p->n_sections = 1;
    }
    return 0;
}

/* Sinumerik: every line translated into the core syntax (one line each, sinumerik.c), in file order, before
 * parsing; the messages keep quoting the file's lines. */
static int translate_sinumerik(Parser *p) {
    SinState *state = malloc(sizeof *state);
    char *out = malloc(SIN_MAX_OUTPUT + 1), expected[512];
    size_t *start = malloc(p->n_lines * sizeof *start), *length = malloc(p->n_lines * sizeof *length);
    size_t used = 0, cap = 0, k;
    int status = 0;
    if (!state || !out || !start || !length) {
        snprintf(p->error, p->error_size, "%s: out of memory", p->file);
        free(state), free(out), free(start), free(length);
        return -1;
    }
    sin_init(state, p->tools, p->n_tools);
    sin_prescan(state, p->text, p->length);
    for (k = 1; k <= p->n_lines && status == 0; k++) {
        size_t n;
        if (sin_translate_line(state, p->raw_text + p->raw_start[k - 1], p->raw_length[k - 1], out, SIN_MAX_OUTPUT + 1,
                               expected, sizeof expected) != 0) {
            fail_at(p, k, "%s", expected);
            status = -1;
            break;
        }
        if (state->note[0] && p->program->n_notes < MAX_NOTES) {
            GcProgram *g = p->program;
            format_line_error(p->raw_text + p->raw_start[k - 1], p->raw_length[k - 1], p->file, k, state->note,
                              g->notes[g->n_notes], NOTE_LENGTH);
            g->n_notes++;
        }
        n = strlen(out);
        if (used + n + 1 > cap) {
            size_t c = cap ? 2 * cap : 4096;
            char *buffer;
            while (c < used + n + 1) c *= 2;
            buffer = realloc(p->translated, c);
            if (!buffer) {
                snprintf(p->error, p->error_size, "%s: out of memory", p->file);
                status = -1;
                break;
            }
            p->translated = buffer, cap = c;
        }
        memcpy(p->translated + used, out, n);
        start[k - 1] = used, length[k - 1] = n;
        used += n;
        p->translated[used++] = '\n';
    }
    if (status == 0 && sin_finish(state, expected, sizeof expected) != 0) {
        fail_at(p, p->n_lines, "%s", expected);
        status = -1;
    }
    free(state);
    free(out);
    if (status != 0) {
        free(start), free(length);
        return -1;
    }
    p->text = p->translated;
    p->length = used;
    p->line_start = start;
    p->line_length = length;
    return 0;
}

void gc_free(GcProgram *program) {
    size_t k;
    if (!program) return;
    for (k = 0; k < program->n_curves; k++) {
        free(program->curves[k].points);
        free(program->curves[k].weights);
        free(program->curves[k].knots);
    }
    free(program->curves);
    free(program->moves);
    memset(program, 0, sizeof *program);
}

int gc_parse(const char *text, size_t length, const char *file, const GcSettings *settings, GcProgram *program,
             char *error, size_t error_size) {
    Parser *p;
    size_t i, line, n_lines = 1;
    int status = 0;
    memset(program, 0, sizeof *program);
    if (error_size) error[0] = '\0';
    p = calloc(1, sizeof *p);
    if (!p) {
        snprintf(error, error_size, "%s: out of memory", file);
        return -1;
    }
    for (i = 0; i < length; i++) n_lines += text[i] == '\n';
    p->line_start = malloc(n_lines * sizeof *p->line_start);
    p->line_length = malloc(n_lines * sizeof *p->line_length);
    if (!p->line_start || !p->line_length) {
        snprintf(error, error_size, "%s: out of memory for %zu lines", file, n_lines);
        free(p->line_start);
        free(p->line_length);
        free(p);
        return -1;
    }
    {
        size_t start = 0, k = 0;
        for (i = 0; i <= length; i++) {
            if (i == length || text[i] == '\n') {
                size_t n = i - start;
                if (n > 0 && text[start + n - 1] == '\r') n--;
                p->line_start[k] = start;
                p->line_length[k] = n;
                k++;
                start = i + 1;
            }
        }
    }
    p->text = text;
    p->length = length;
    p->file = file;
    p->n_lines = n_lines;
    p->error = error;
    p->error_size = error_size;
    p->program = program;
    memcpy(p->offsets, settings->offsets, sizeof p->offsets);
    memcpy(p->position, settings->start, sizeof p->position);
    memcpy(p->home, settings->home, sizeof p->home);
    p->dialect = settings->dialect;
    p->tools = settings->tools;
    p->n_tools = settings->tools ? settings->n_tools : 0;
    p->absolute = 1;
    p->plane = 17;
    p->motion = -1;
    p->pending_tool = -1;
    memcpy(program->start, settings->start, sizeof program->start);
    memcpy(program->start_offset, settings->offsets[0], sizeof program->start_offset);
    p->raw_text = text;
    p->raw_start = p->line_start;
    p->raw_length = p->line_length;
    if (p->dialect == DIALECT_SINUMERIK) status = translate_sinumerik(p);
    if (status == 0) status = scan_sections(p);
    line = 1;
    if (status == 0 && p->sections[p->main_section].o_line > 0) line = p->sections[p->main_section].o_line;
    while (status == 0) {
        size_t next;
        if (p->depth) {
            const Call *call = &p->stack[p->depth - 1];
            if (line >= p->sections[call->section].end) {
                fail_at(p, call->line, "M99 at the end of the subprogram O%ld", p->sections[call->section].number);
                status = -1;
                break;
            }
            if (++p->called_lines > MAX_CALLED_LINES) {
                fail_at(p, line, "at most %d lines executed in subprogram calls", MAX_CALLED_LINES);
                status = -1;
                break;
            }
        }
        if (line > n_lines) break;
        if (parse_line(p, line, &next) != 0) {
            status = -1;
            break;
        }
        line = next;
    }
    if (status == 0) spindle_now(p, &program->final_spindle, &program->final_spindle_on);
    /* G41/G42: the moves carry side and radius; the compensation stage offsets them (or refuses a line) */
    if (status == 0) status = cutter_compensate(program, text, length, file, error, error_size);
    free(p->sections);
    free(p->section_at);
    if (p->line_start != p->raw_start) {
        free(p->line_start);
        free(p->line_length);
    }
    free(p->raw_start);
    free(p->raw_length);
    free(p->translated);
    free(p);
    if (status != 0) gc_free(program);
    return status;
}
