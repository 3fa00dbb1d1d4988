/* G-code parser: the subset documented in models/interpolator/parser.py, line by line, with the
 * same checks and the same arithmetic as that reference. Every malformed line is an error naming the line,
 * its text and what was expected; nothing is skipped. Bounded work per byte: safe on any input (fuzzed). */
#include "gcode_parser.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define MAX_WORDS 512

static const double POW10[23] = {1e0,  1e1,  1e2,  1e3,  1e4,  1e5,  1e6,  1e7,  1e8,  1e9,  1e10, 1e11,
                                 1e12, 1e13, 1e14, 1e15, 1e16, 1e17, 1e18, 1e19, 1e20, 1e21, 1e22};

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

enum { G_MOTION, G_G10, G_PLANE, G_UNITS, G_DISTANCE, G_OFFSET, G_GROUPS };
enum { M_SPINDLE, M_END, M_GROUPS };
static const char *const G_GROUP_NAMES[G_GROUPS] = {"motion", "g10", "plane", "units", "distance", "offset"};
static const char *const M_GROUP_NAMES[M_GROUPS] = {"spindle", "end"};

typedef struct {
    const char *text;
    size_t length;
    const char *file;
    /* line index: start offset and length of each line (without '\n' and a trailing '\r') */
    size_t *line_start;
    size_t *line_length;
    size_t n_lines;
    char *error;
    size_t error_size;
    GcProgram *program;
    double offsets[6][3];
    int active_offset;
    double position[3];
    int inch, absolute, plane, motion;
    double feed, speed;
    int spindle_dir;
    int ended;
    int block;
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
    format_line_error(known ? p->text + p->line_start[line - 1] : "", known ? p->line_length[line - 1] : 0, p->file,
                      line, expected, p->error, p->error_size);
}

static double length_of(const Parser *p, double value) { return p->inch ? value * 0.0254 : value / 1000.0; }
static double unit_factor(const Parser *p) { return p->inch ? 0.0254 : 1e-3; }

static int is_letter(char c) { return (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z'); }
static int is_digit(char c) { return c >= '0' && c <= '9'; }

/* The number after a letter (spaces allowed before it); -1 on error (reported). */
static int parse_number(Parser *p, size_t line, const char *s, size_t n, size_t *i, char letter, double *value,
                        const char **text, int *text_length) {
    size_t start;
    int negative = 0, digits = 0, scale = 0, seen_point = 0, any_digit = 0;
    unsigned long long mantissa = 0;
    while (*i < n && (s[*i] == ' ' || s[*i] == '\t')) (*i)++;
    start = *i;
    if (*i < n && (s[*i] == '+' || s[*i] == '-')) {
        negative = s[*i] == '-';
        (*i)++;
    }
    while (*i < n && (is_digit(s[*i]) || (s[*i] == '.' && !seen_point))) {
        if (s[*i] == '.') {
            seen_point = 1;
        } else {
            int d = s[*i] - '0';
            any_digit = 1;
            if (mantissa == 0 && d == 0) {
                if (seen_point) scale++;
            } else {
                digits++;
                if (digits > MAX_SIGNIFICANT_DIGITS) {
                    fail_at(p, line, "at most %d significant digits in the number after '%c'", MAX_SIGNIFICANT_DIGITS,
                            letter);
                    return -1;
                }
                mantissa = mantissa * 10u + (unsigned)d;
                if (seen_point) scale++;
            }
        }
        (*i)++;
    }
    if (!any_digit) {
        fail_at(p, line, "a number after '%c'", letter);
        return -1;
    }
    while (scale > 0 && mantissa % 10u == 0 && mantissa != 0) {
        mantissa /= 10u;
        scale--;
    }
    if (mantissa == 0) scale = 0;
    if (scale > 22) {
        fail_at(p, line, "at most 22 decimals in the number after '%c'", letter);
        return -1;
    }
    *value = scale ? (double)mantissa / POW10[scale] : (double)mantissa;
    if (negative) *value = -*value;
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
        } else if (is_letter(c)) {
            char letter = (char)(c >= 'a' ? c - 'a' + 'A' : c);
            Word *w;
            if (!strchr("GMNXYZIJKRFSPL", letter)) {
                fail_at(p, line, "a word G, M, N, X, Y, Z, I, J, K, R, F, S, P or L, got '%c'", c);
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
                fail_at(p, line, "a word (letter and number), a comment or the end of the line, got '%c'", c);
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

static int g_code(Parser *p, size_t line, const Word *w) {
    double tenths_value = w->value * 10.0;
    long tenths = w->value >= 0.0 && tenths_value < 1e6 ? (long)floor(tenths_value + 0.5) : -1;
    static const long known[] = {0, 10, 20, 30, 62, 100, 170, 180, 190, 200, 210, 540, 550, 560, 570, 580, 590, 900, 910};
    size_t k;
    if (tenths >= 0 && fabs(tenths_value - (double)tenths) <= 1e-9)
        for (k = 0; k < sizeof known / sizeof known[0]; k++)
            if (known[k] == tenths) return (int)tenths;
    fail_at(p, line, "a supported G code (G0 G1 G2 G3 G6.2 G10 G17 G18 G19 G20 G21 G54-G59 G90 G91), got G%.*s",
            w->text_length, w->text);
    return -1;
}

static int g_group(int code) {
    switch (code) {
    case 0: case 10: case 20: case 30: case 62: return G_MOTION;
    case 100: return G_G10;
    case 170: case 180: case 190: return G_PLANE;
    case 200: case 210: return G_UNITS;
    case 900: case 910: return G_DISTANCE;
    default: return G_OFFSET;
    }
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

static GcMove *new_move(Parser *p, int kind, size_t line) {
    GcMove *m;
    if (grow_moves(p) != 0) return NULL;
    m = &p->program->moves[p->program->n_moves++];
    memset(m, 0, sizeof *m);
    m->kind = kind;
    m->line = (int)line;
    m->block = p->block;
    memcpy(m->start, p->position, sizeof m->start);
    memcpy(m->offset, p->offsets[p->active_offset], sizeof m->offset);
    spindle_now(p, &m->spindle, &m->spindle_on);
    m->curve = -1;
    m->axes[0] = 0, m->axes[1] = 1, m->axes[2] = 2;
    return m;
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
    const double *off = p->offsets[p->active_offset];
    int a;
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

static int need_feed(Parser *p, size_t line) {
    if (p->feed <= 0.0) {
        fail_at(p, line, "F (feed) before the first feed move (G1, G2, G3, G6.2)");
        return -1;
    }
    return 0;
}

static int straight(Parser *p, size_t line) {
    double end[3], dx, dy, dz;
    int rapid = p->motion == 0;
    GcMove *m;
    if (target(p, line, end) != 0) return -1;
    if (!rapid && need_feed(p, line) != 0) return -1;
    dx = end[0] - p->position[0], dy = end[1] - p->position[1], dz = end[2] - p->position[2];
    if (dx * dx + dy * dy + dz * dz <= 0.0) return 0;
    m = new_move(p, rapid ? MOVE_RAPID : MOVE_LINE, line);
    if (!m) return -1;
    memcpy(m->end, end, sizeof m->end);
    m->feed = rapid ? 0.0 : p->feed;
    memcpy(p->position, end, sizeof end);
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
    m->feed = p->feed;
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
    if (p->m[M_SPINDLE] >= 0) p->spindle_dir = p->m[M_SPINDLE] == 3 ? 1 : p->m[M_SPINDLE] == 4 ? -1 : 0;
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
            int code = g_code(p, line, w), group;
            if (code < 0) return -1;
            group = g_group(code);
            if (p->g[group] >= 0) {
                fail_at(p, line, "one G code of the %s group per line, got G%g and G%.*s", G_GROUP_NAMES[group],
                        (double)p->g[group] / 10.0, w->text_length, w->text);
                return -1;
            }
            p->g[group] = code;
        } else if (w->letter == 'M') {
            double v = w->value;
            int code, group;
            if (v != 2.0 && v != 3.0 && v != 4.0 && v != 5.0 && v != 30.0) {
                fail_at(p, line, "a supported M code (M2 M3 M4 M5 M30), got M%.*s", w->text_length, w->text);
                return -1;
            }
            code = (int)v;
            group = (code == 2 || code == 30) ? M_END : M_SPINDLE;
            if (p->m[group] >= 0) {
                fail_at(p, line, "one M code of the %s group per line, got M%d and M%.*s", M_GROUP_NAMES[group],
                        p->m[group], w->text_length, w->text);
                return -1;
            }
            p->m[group] = code;
        } else if (w->letter == 'N') {
            int any = 0, j;
            for (j = 0; j < 26; j++) any |= p->slots[j].present;
            for (j = 0; j < G_GROUPS; j++) any |= p->g[j] >= 0;
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
        if (tokenize(p, k) != 0) return -1;
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

static int nurbs(Parser *p, size_t first_line, size_t *last_line) {
    GcProgram *g = p->program;
    GcCurve curve;
    size_t cap = 0, line = first_line, end_line, n_knots = 0, n_points, j;
    int degree = 3, trailing = 0, k, index;
    double previous[3];
    const double *off = p->offsets[p->active_offset];
    double *breaks = NULL;
    size_t n_breaks = 0;
    memset(&curve, 0, sizeof curve);
    if (!p->absolute) {
        fail_at(p, line, "G90 (absolute coordinates) for a NURBS block");
        return -1;
    }
    if (p->g[G_G10] >= 0) {
        fail_at(p, line, "no G10 in a NURBS line");
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
            static const char axes[3] = {'X', 'Y', 'Z'};
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
            for (a = 0; a < 3; a++) {
                if (has(p, axes[a])) {
                    double value = val(p, axes[a]);
                    if (check_coordinate(p, line, value) != 0) goto error;
                    pt[a] = length_of(p, value) + off[a];
                } else {
                    pt[a] = previous[a];
                }
            }
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
    /* store the curve */
    if (g->n_curves == g->cap_curves) {
        size_t c = g->cap_curves ? 2 * g->cap_curves : 8;
        GcCurve *cs = realloc(g->curves, c * sizeof *cs);
        if (!cs) {
            snprintf(p->error, p->error_size, "%s: out of memory for %zu curves", p->file, c);
            goto error;
        }
        g->curves = cs;
        g->cap_curves = c;
    }
    index = (int)g->n_curves;
    g->curves[g->n_curves++] = curve;
    memset(&curve, 0, sizeof curve);
    {
        const GcCurve *c = &g->curves[index];
        const double *kn = c->knots;
        double *last_point = c->points + 3 * (n_points - 1);
        size_t b;
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
        for (b = 0; b + 1 < n_breaks; b++) {
            GcMove *mv = new_move(p, MOVE_NURBS, first_line);
            if (!mv) {
                free(breaks);
                return -1;
            }
            memcpy(mv->end, last_point, sizeof mv->end);
            memcpy(mv->offset, off, sizeof mv->offset);
            mv->feed = p->feed;
            mv->curve = index;
            mv->u0 = breaks[b];
            mv->u1 = breaks[b + 1];
        }
        memcpy(p->position, last_point, sizeof p->position);
        free(breaks);
    }
    p->program->final_line = (int)end_line;
    *last_line = end_line;
    return 0;
error:
    free(curve.points);
    free(curve.weights);
    free(curve.knots);
    return -1;
}

/* One line; *next is the last line consumed (a NURBS block takes several). */
static int parse_line(Parser *p, size_t line, size_t *last) {
    int motion_g;
    *last = line;
    if (p->line_length[line - 1] > MAX_LINE_LENGTH) {
        fail_at(p, line, "a line of at most %d characters", MAX_LINE_LENGTH);
        return -1;
    }
    if (is_tape_mark(p, line)) return 0;
    if (tokenize(p, line) != 0) return -1;
    if (!p->n_words) return 0;
    if (p->ended) {
        fail_at(p, line, "nothing after the program end (M2/M30 in line %d)", p->ended);
        return -1;
    }
    p->program->final_line = (int)line;
    if (classify(p, line) != 0) return -1;
    p->block = has(p, 'N') ? (int)val(p, 'N') : 0;
    p->program->final_block = p->block;
    motion_g = p->g[G_MOTION];
    if (motion_g == 62) return nurbs(p, line, last);
    if (set_feed_and_speed(p, line) != 0) return -1;
    if (p->g[G_PLANE] >= 0) p->plane = p->g[G_PLANE] / 10;
    if (p->g[G_UNITS] >= 0) p->inch = p->g[G_UNITS] == 200;
    if (p->g[G_DISTANCE] >= 0) p->absolute = p->g[G_DISTANCE] == 900;
    if (p->g[G_OFFSET] >= 0) p->active_offset = (p->g[G_OFFSET] - 540) / 10;
    if (has(p, 'P') && p->g[G_G10] < 0) {
        fail_at(p, line, "P only with G10 (or P with G6.2)");
        return -1;
    }
    if (has(p, 'L') && p->g[G_G10] < 0) {
        fail_at(p, line, "L only with G10 (or P with G6.2)");
        return -1;
    }
    if (p->g[G_G10] >= 0) {
        double pv;
        int a, index;
        static const char axes[3] = {'X', 'Y', 'Z'};
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
    } else {
        int has_axes = has(p, 'X') || has(p, 'Y') || has(p, 'Z'), a;
        char arc_word = 0;
        for (a = 0; a < 4 && !arc_word; a++)
            if (has(p, "IJKR"[a])) arc_word = "IJKR"[a];
        if (motion_g >= 0) p->motion = motion_g;
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
            if (has_axes && straight(p, line) != 0) return -1;
        } else if (arc_word) {
            fail_at(p, line, "%c only with G2/G3 (or in a NURBS block)", arc_word);
            return -1;
        }
    }
    if (p->m[M_END] >= 0) p->ended = (int)line;
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
    p->absolute = 1;
    p->plane = 17;
    p->motion = -1;
    memcpy(program->start, settings->start, sizeof program->start);
    memcpy(program->start_offset, settings->offsets[0], sizeof program->start_offset);
    for (line = 1; line <= n_lines; line++) {
        size_t last;
        if (parse_line(p, line, &last) != 0) {
            status = -1;
            break;
        }
        line = last;
    }
    if (status == 0) spindle_now(p, &program->final_spindle, &program->final_spindle_on);
    free(p->line_start);
    free(p->line_length);
    free(p);
    if (status != 0) gc_free(program);
    return status;
}
