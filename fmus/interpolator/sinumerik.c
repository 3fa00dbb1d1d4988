/* Sinumerik 840D -> core G-code, one line at a time: the translator of models/interpolator/sinumerik.py (the
 * reference: its docstring documents the forms and cites the manuals), function for function, with the same
 * checks in the same order, the same arithmetic and the same messages. Bounded work per byte (no recursion
 * deeper than SIN_MAX_NESTING, at most SIN_MAX_TOKENS words a line); no state outside SinState. */
#include "sinumerik.h"

#include "gcode_number.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#define MAX_SIGNIFICANT MAX_SIGNIFICANT_DIGITS
#define VALUE_LIMIT 1e9

static const double POW10[23] = {1e0,  1e1,  1e2,  1e3,  1e4,  1e5,  1e6,  1e7,  1e8,  1e9,  1e10, 1e11,
                                 1e12, 1e13, 1e14, 1e15, 1e16, 1e17, 1e18, 1e19, 1e20, 1e21, 1e22};
static const double DEGREE = 3.14159265358979323846 / 180.0;

/* accepted, not modelled (order = the Python NOTED table: bit index of SinState.noted) */
static const char *const NOTED[][2] = {
    {"G601", "exact-stop window fine"},
    {"G602", "exact-stop window coarse"},
    {"G603", "exact stop at the interpolation end"},
    {"G450", "corners of the radius compensation as arcs"},
    {"G451", "corners of the radius compensation at the intersection"},
    {"SOFT", "jerk-limited acceleration"},
    {"BRISK", "acceleration without jerk limit"},
    {"FFWON", "feedforward control"},
    {"FFWOF", "feedforward control off"},
    {"COMPOF", "compressor off"},
    {"COMPCAD", "compressor"},
    {"COMPCURV", "compressor"},
    {"COMPSURF", "compressor"},
    {"UPATH", "path parameter of following axes"},
    {"SPATH", "path parameter of following axes"},
    {"FNORM", "feed normal"},
    {"CFC", "feed at the contour"},
    {"CFTCP", "feed at the tool centre"},
    {"CFIN", "feed at inner arcs"},
    {"DIAMOF", "diameter programming off"},
    {"TRAFOOF", "transformation off"},
    {"STOPRE", "preprocessing stop"},
    {"ADISPOS", "rounding of rapid moves"},
    {"MSG", "operator message"},
    {"WORKPIECE", "blank for the control's simulation"},
    {"CUT2D", "2D radius compensation in the plane"},
    {"CUT2DF", "2D radius compensation in the frame's plane"},
};
#define N_NOTED ((int)(sizeof NOTED / sizeof NOTED[0]))

static const char *const REFUSED[][2] = {
    {"MCALL", "modal subprogram calls"},
    {"GOTO", "program jumps"},
    {"GOTOF", "program jumps"},
    {"GOTOB", "program jumps"},
    {"GOTOC", "program jumps"},
    {"IF", "control structures"},
    {"ELSE", "control structures"},
    {"ENDIF", "control structures"},
    {"WHILE", "control structures"},
    {"ENDWHILE", "control structures"},
    {"FOR", "control structures"},
    {"ENDFOR", "control structures"},
    {"REPEAT", "control structures"},
    {"UNTIL", "control structures"},
    {"LOOP", "control structures"},
    {"ENDLOOP", "control structures"},
    {"CASE", "control structures"},
    {"DEF", "variable definitions: use R0 to R99"},
    {"CIP", "circles through an intermediate point"},
    {"CT", "tangential circles"},
    {"ASPLINE", "Akima splines: only BSPLINE"},
    {"CSPLINE", "cubic splines: only BSPLINE"},
    {"ROTS", "frame rotation is not modelled"},
    {"AROTS", "frame rotation is not modelled"},
    {"CROTS", "frame rotation is not modelled"},
    {"TOFRAME", "frame rotation is not modelled"},
    {"TRAORI", "5-axis transformations"},
    {"TRANSMIT", "kinematic transformations"},
    {"TRACYL", "kinematic transformations"},
    {"AC", "absolute dimensions per word: program G90"},
    {"IC", "incremental dimensions per word: program G91"},
    {"PROC", "a PROC line of its own, without parameters"},
};
#define N_REFUSED ((int)(sizeof REFUSED / sizeof REFUSED[0]))

static const char *const FUNCTIONS[] = {"SIN", "COS", "TAN", "SQRT", "ABS", "POT", "TRUNC"};
#define N_FUNCTIONS ((int)(sizeof FUNCTIONS / sizeof FUNCTIONS[0]))

/* keywords: frame words first (FRAME_WORDS of the Python), then PROC attributes */
enum { K_TRANS, K_ATRANS, K_ROT, K_AROT, K_SCALE, K_ASCALE, K_MIRROR, K_AMIRROR, K_SAVE, K_DISPLOF, K_DISPLON,
       K_SBLOF, K_SBLON, K_BSPLINE, K_RET, K_SUPA, K_COUNT };
static const char *const KEYWORDS[K_COUNT] = {"TRANS", "ATRANS", "ROT",     "AROT",    "SCALE",   "ASCALE",
                                              "MIRROR", "AMIRROR", "SAVE",  "DISPLOF", "DISPLON", "SBLOF",
                                              "SBLON", "BSPLINE", "RET",  "SUPA"};
#define IS_FRAME(k) ((k) <= K_AMIRROR)
#define IS_PROC_ATTRIBUTE(k) ((k) >= K_SAVE && (k) <= K_SBLON)

enum { NAMED_SD, NAMED_PW, NAMED_PL, NAMED_ADIS, NAMED_ADISPOS, NAMED_CR, NAMED_RPL, NAMED_COUNT };
static const char *const NAMED[NAMED_COUNT] = {"SD", "PW", "PL", "ADIS", "ADISPOS", "CR", "RPL"};

static const char NUMBER_LETTERS[] = "NGMXYZIJKFSTDP";

enum { TK_N, TK_W, TK_NAMED, TK_K, TK_CALL, TK_NOTE, TK_CYCLE832, TK_PROC };

typedef struct {
    int kind;
    char letter; /* TK_W */
    int id;      /* TK_NAMED: NAMED_*; TK_K: K_* or K_COUNT + noted index; TK_NOTE: noted index */
    double value;
    const char *text; /* TK_N, TK_W: the number as written; NULL: `buf` */
    int text_length;
    char buf[SIN_NAME_LENGTH + 1]; /* formatted value, or the upper-case name of TK_CALL / TK_PROC */
} Token;

typedef struct {
    SinState *st;
    const char *s;
    size_t n;
    char *expected;
    size_t expected_size;
    Token tokens[SIN_MAX_TOKENS];
    int n_tokens;
} Ctx;

typedef struct {
    char buf[SIN_MAX_OUTPUT + 2];
    size_t total; /* characters of the whole output, also beyond buf */
} Out;

static int fail(Ctx *c, const char *format, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 2, 3)))
#endif
    ;

static int fail(Ctx *c, const char *format, ...) {
    va_list args;
    va_start(args, format);
    if (c->expected_size > 0) vsnprintf(c->expected, c->expected_size, format, args);
    va_end(args);
    return -1;
}

static void put(Out *o, const char *format, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 2, 3)))
#endif
    ;

/* Appends one piece, separated by a blank from the one before. */
static void put(Out *o, const char *format, ...) {
    char piece[SIN_MAX_OUTPUT + 2];
    size_t length, room, copy;
    int written;
    va_list args;
    va_start(args, format);
    written = vsnprintf(piece, sizeof piece, format, args);
    va_end(args);
    if (written < 0) written = 0;
    length = (size_t)written;
    if (o->total > 0) {
        if (o->total < sizeof o->buf - 1) o->buf[o->total] = ' ';
        o->total++;
    }
    room = o->total < sizeof o->buf - 1 ? sizeof o->buf - 1 - o->total : 0;
    copy = length < room ? length : room;
    if (length > sizeof piece - 1) copy = copy < sizeof piece - 1 ? copy : sizeof piece - 1;
    if (copy > 0) memcpy(o->buf + o->total, piece, copy);
    o->total += length;
    o->buf[o->total < sizeof o->buf - 1 ? o->total : sizeof o->buf - 1] = '\0';
}

static int is_letter(char c) { return (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z'); }
static int is_digit(char c) { return c >= '0' && c <= '9'; }
static int is_name_char(char c) { return is_letter(c) || is_digit(c) || c == '_'; }
static int is_blank(char c) { return c == ' ' || c == '\t'; }
static char upper(char c) { return (char)(c >= 'a' && c <= 'z' ? c - 'a' + 'A' : c); }

/* "'c'", "byte 0x..", "a non-ASCII character" */
static void shown(char c, char out[32]) {
    unsigned char u = (unsigned char)c;
    if (u > 32 && u < 127)
        snprintf(out, 32, "'%c'", c);
    else if (u < 128)
        snprintf(out, 32, "byte 0x%02x", u);
    else
        snprintf(out, 32, "a non-ASCII character");
}

/* at most size - 1 characters of src, terminated */
static void copy_name(char *dst, size_t size, const char *src) {
    size_t k = 0;
    while (k + 1 < size && src[k]) {
        dst[k] = src[k];
        k++;
    }
    dst[k] = '\0';
}

/* upper-case copy of s[i, j) (j - i <= SIN_MAX_WORD) */
static void upper_copy(const char *s, size_t i, size_t j, char *out) {
    size_t k;
    for (k = i; k < j; k++) out[k - i] = upper(s[k]);
    out[j - i] = '\0';
}

static int control_free(const char *s, size_t length) {
    size_t k;
    for (k = 0; k < length; k++)
        if ((unsigned char)s[k] < 32 || s[k] == 127) return 0;
    return 1;
}

static int in_list(const char *word, const char *const *list, int n) {
    int k;
    for (k = 0; k < n; k++)
        if (strcmp(word, list[k]) == 0) return k;
    return -1;
}

static int noted_index(const char *word) {
    int k;
    for (k = 0; k < N_NOTED; k++)
        if (strcmp(word, NOTED[k][0]) == 0) return k;
    return -1;
}

static const char *refused_reason(const char *word) {
    int k;
    for (k = 0; k < N_REFUSED; k++)
        if (strcmp(word, REFUSED[k][0]) == 0) return REFUSED[k][1];
    return NULL;
}

/* format_value of the Python: plain decimal, at most 10 decimals and 17 significant digits */
static int format_value(Ctx *c, double x, char out[32]) {
    double a = fabs(x);
    int int_digits = 0, decimals, k;
    size_t n, point;
    if (!(a < VALUE_LIMIT)) return fail(c, "a computed value of magnitude below 1000000000");
    for (k = 0; k < 9; k++)
        if (a >= POW10[k]) int_digits++;
    decimals = 10 < MAX_SIGNIFICANT - int_digits ? 10 : MAX_SIGNIFICANT - int_digits;
    snprintf(out, 32, "%.*f", decimals, x);
    n = strlen(out);
    point = (size_t)(strchr(out, '.') - out);
    while (n > point + 1 && out[n - 1] == '0') n--;
    if (n == point + 1) n--;
    out[n] = '\0';
    if (strcmp(out, "-0") == 0 || n == 0 || strcmp(out, "-") == 0) strcpy(out, "0");
    return 0;
}

static int push(Ctx *c, Token **t) {
    if (c->n_tokens >= SIN_MAX_TOKENS) return fail(c, "at most %d words in a line", SIN_MAX_TOKENS);
    *t = &c->tokens[c->n_tokens++];
    memset(*t, 0, sizeof **t);
    return 0;
}

static int word_end(Ctx *c, size_t i, size_t *end) {
    size_t j = i;
    while (j < c->n && is_name_char(c->s[j])) j++;
    if (j - i > SIN_MAX_WORD) return fail(c, "a word of at most %d characters", SIN_MAX_WORD);
    *end = j;
    return 0;
}

/* A plain number at s[i]: [+-]digits[.digits]; the core's arithmetic (gc_read_number). */
static int number(Ctx *c, size_t *i, const char *what, double *value, size_t *start) {
    NumberStatus status;
    *start = *i;
    status = gc_read_number(c->s, c->n, i, value);
    if (status != NUMBER_OK) {
        char expected[160];
        gc_number_expected(status, what, expected, sizeof expected);
        return fail(c, "%s", expected);
    }
    return 0;
}

static size_t skip(const Ctx *c, size_t i, int depth) {
    if (depth > 0)
        while (i < c->n && is_blank(c->s[i])) i++;
    return i;
}

static int expression(Ctx *c, size_t *i, int depth, const char *what, double *value);

static double function(int f, double x) {
    if (f <= 2) { /* SIN COS TAN */
        double a = x * DEGREE;
        if (isinf(a)) return NAN;
        return f == 0 ? sin(a) : f == 1 ? cos(a) : tan(a);
    }
    if (f == 3) return sqrt(x);
    if (f == 4) return fabs(x);
    if (f == 5) return x * x;
    return isfinite(x) ? trunc(x) : x;
}

static int primary(Ctx *c, size_t *i, int depth, const char *what, double *value) {
    const char *s = c->s;
    size_t n = c->n, start, j, k;
    char name[SIN_MAX_WORD + 2], got[32];
    if (*i < n && (is_digit(s[*i]) || s[*i] == '.')) return number(c, i, what, value, &start);
    if (*i < n && s[*i] == '(') {
        if (depth >= SIN_MAX_NESTING)
            return fail(c, "at most %d nested parentheses in the expression after %s", SIN_MAX_NESTING, what);
        (*i)++;
        if (expression(c, i, depth + 1, what, value) < 0) return -1;
        *i = skip(c, *i, depth + 1);
        if (*i >= n || s[*i] != ')') return fail(c, "')' to close the parenthesis in the expression after %s", what);
        (*i)++;
        return 0;
    }
    if (*i < n && s[*i] == '$') {
        if (word_end(c, *i + 1, &j) < 0) return -1;
        upper_copy(s, *i, j, name);
        return fail(c, "%s is not supported (system variables: use R0 to R99)", name);
    }
    if (*i < n && (is_letter(s[*i]) || s[*i] == '_')) {
        size_t length;
        int all_digits = 1, f;
        if (word_end(c, *i, &j) < 0) return -1;
        upper_copy(s, *i, j, name);
        length = j - *i;
        for (k = 1; k < length; k++)
            if (!is_digit(name[k])) all_digits = 0;
        if (name[0] == 'R' && length > 1 && all_digits) {
            int index = SIN_R_COUNT;
            if (length <= 4) {
                index = 0;
                for (k = 1; k < length; k++) index = index * 10 + (name[k] - '0');
            }
            if (index >= SIN_R_COUNT) return fail(c, "an R parameter R0 to R%d, got %s", SIN_R_COUNT - 1, name);
            if (!c->st->r_set[index]) return fail(c, "R%d set before it is used (R%d=...)", index, index);
            if (c->st->r_section[index] != c->st->section)
                return fail(c, "R%d set in this program section before it is used (R parameters are evaluated once, "
                               "in the order of the file, not per subprogram call)", index);
            *value = c->st->r[index];
            *i = j;
            return 0;
        }
        k = skip(c, j, depth + 1);
        if (k < n && s[k] == '(') {
            double arg;
            f = in_list(name, FUNCTIONS, N_FUNCTIONS);
            if (f < 0) {
                if (strcmp(name, "AC") == 0 || strcmp(name, "IC") == 0)
                    return fail(c, "%s is not supported (%s)", name, refused_reason(name));
                return fail(c, "the function %s is not supported (SIN, COS, TAN, SQRT, ABS, POT, TRUNC)", name);
            }
            if (depth >= SIN_MAX_NESTING)
                return fail(c, "at most %d nested parentheses in the expression after %s", SIN_MAX_NESTING, what);
            k++;
            if (expression(c, &k, depth + 1, what, &arg) < 0) return -1;
            k = skip(c, k, depth + 1);
            if (k >= n || s[k] != ')') return fail(c, "')' to close %s( in the expression after %s", name, what);
            if (f == 3 && arg < 0.0) return fail(c, "SQRT of a number >= 0");
            *value = function(f, arg);
            *i = k + 1;
            return 0;
        }
        return fail(c, "a number, an R parameter, '(' or a function in the expression after %s, got %s", what, name);
    }
    if (*i < n)
        shown(s[*i], got);
    else
        snprintf(got, sizeof got, "the end of the line");
    return fail(c, "a number, an R parameter, '(' or a function in the expression after %s, got %s", what, got);
}

static int unary(Ctx *c, size_t *i, int depth, const char *what, double *value) {
    int negative = 0;
    *i = skip(c, *i, depth);
    while (*i < c->n && (c->s[*i] == '+' || c->s[*i] == '-')) {
        if (c->s[*i] == '-') negative = !negative;
        *i = skip(c, *i + 1, depth);
    }
    if (primary(c, i, depth, what, value) < 0) return -1;
    if (negative) *value = -*value;
    return 0;
}

static int term(Ctx *c, size_t *i, int depth, const char *what, double *value) {
    if (unary(c, i, depth, what, value) < 0) return -1;
    for (;;) {
        size_t j = skip(c, *i, depth);
        double right;
        char op;
        if (!(j < c->n && (c->s[j] == '*' || c->s[j] == '/'))) return 0;
        op = c->s[j];
        *i = j + 1;
        if (unary(c, i, depth, what, &right) < 0) return -1;
        if (op == '*') {
            *value = *value * right;
        } else {
            if (right == 0.0) return fail(c, "no division by zero in the expression after %s", what);
            *value = *value / right;
        }
    }
}

static int expression(Ctx *c, size_t *i, int depth, const char *what, double *value) {
    if (term(c, i, depth, what, value) < 0) return -1;
    for (;;) {
        size_t j = skip(c, *i, depth);
        double right;
        char op;
        if (!(j < c->n && (c->s[j] == '+' || c->s[j] == '-'))) return 0;
        op = c->s[j];
        *i = j + 1;
        if (term(c, i, depth, what, &right) < 0) return -1;
        *value = op == '+' ? *value + right : *value - right;
    }
}

/* The expression after '=' (blanks after '=' allowed), finite. */
static int eval_value(Ctx *c, size_t *i, const char *what, double *value) {
    while (*i < c->n && is_blank(c->s[*i])) (*i)++;
    if (expression(c, i, 0, what, value) < 0) return -1;
    if (*i < c->n && !is_blank(c->s[*i]) && c->s[*i] != ';') {
        char got[32];
        shown(c->s[*i], got);
        return fail(c, "an operator, a blank or the end of the line after the value of %s=, got %s", what, got);
    }
    if (!isfinite(*value)) return fail(c, "a finite value of the expression after %s", what);
    return 0;
}

/* s[i] == '(': the index after the matching ')' (quoted strings skipped) */
static int skip_parenthesis(Ctx *c, size_t i, const char *name, size_t *end) {
    int depth = 0, quoted = 0;
    while (i < c->n) {
        char ch = c->s[i];
        if (quoted) {
            if (ch == '"') quoted = 0;
        } else if (ch == '"') {
            quoted = 1;
        } else if (ch == '(') {
            depth++;
        } else if (ch == ')') {
            depth--;
            if (depth == 0) {
                *end = i + 1;
                return 0;
            }
        }
        i++;
    }
    return fail(c, "')' to close %s(", name);
}

static const char *letter_refusal(char letter, char buf[160]) {
    if (strchr("ABCUVWE", letter) && letter != '\0')
        snprintf(buf, 160, "%c is not supported (rotary and additional axes: X, Y, Z only)", letter);
    else if (letter == 'H')
        snprintf(buf, 160, "H is not supported (auxiliary functions)");
    else if (letter == 'R')
        snprintf(buf, 160, "R<n>=<value> (R parameters are assigned with =)");
    else
        snprintf(buf, 160, "%c is not supported (a word N, G, M, X, Y, Z, I, J, K, F, S, T, D, L, P or R<n>=)",
                 letter);
    return buf;
}

static int is_number_letter(char letter) { return letter != '\0' && strchr(NUMBER_LETTERS, letter) != NULL; }

static int tool_by_name(const SinState *st, const char *name, size_t length) {
    size_t k;
    for (k = 0; k < st->n_tools; k++)
        if (strlen(st->tools[k].name) == length && length > 0 && memcmp(st->tools[k].name, name, length) == 0)
            return (int)k;
    return -1;
}

static int subprogram_index(const SinState *st, const char *upper_name) {
    int k;
    for (k = 0; k < st->n_subprograms; k++)
        if (strcmp(st->subprograms[k], upper_name) == 0) return k;
    return -1;
}

static int register_subprogram(SinState *st, const char *upper_name) {
    int k = subprogram_index(st, upper_name);
    if (k >= 0) return k;
    if (st->n_subprograms >= SIN_MAX_SUBPROGRAMS) return -1;
    copy_name(st->subprograms[st->n_subprograms], SIN_NAME_LENGTH + 1, upper_name);
    return st->n_subprograms++;
}

static int named(Ctx *c, const char *word, size_t *i) {
    const char *s = c->s;
    size_t n = c->n;
    Token *t = NULL;
    char buf[160];
    double value;
    int id;
    if (strcmp(word, "T") == 0) {
        size_t j = *i;
        while (j < n && is_blank(s[j])) j++;
        if (j < n && s[j] == '"') {
            const char *e = memchr(s + j + 1, '"', n - j - 1);
            size_t length;
            int k;
            if (!e) return fail(c, "a closing '\"' after T=\"");
            length = (size_t)(e - (s + j + 1));
            if (length > SIN_NAME_LENGTH) return fail(c, "a tool name of at most %d characters", SIN_NAME_LENGTH);
            if (!control_free(s + j + 1, length)) return fail(c, "a tool name without control characters");
            k = tool_by_name(c->st, s + j + 1, length);
            if (k < 0)
                return fail(c, "a tool named \"%.*s\" in the tool table (none has this name)", (int)length, s + j + 1);
            if (push(c, &t) < 0) return -1;
            t->kind = TK_W;
            t->letter = 'T';
            t->value = (double)c->st->tools[k].number;
            snprintf(t->buf, sizeof t->buf, "%d", c->st->tools[k].number);
            *i = (size_t)(e - s) + 1;
            return 0;
        }
    }
    if (strlen(word) == 1 && is_number_letter(word[0]) && !strchr("NGMP", word[0])) {
        char formatted[32];
        if (eval_value(c, i, word, &value) < 0 || format_value(c, value, formatted) < 0 || push(c, &t) < 0) return -1;
        t->kind = TK_W;
        t->letter = word[0];
        t->value = value;
        memcpy(t->buf, formatted, sizeof formatted);
        return 0;
    }
    id = in_list(word, NAMED, NAMED_COUNT);
    if (id >= 0) {
        char formatted[32];
        if (eval_value(c, i, word, &value) < 0 || format_value(c, value, formatted) < 0 || push(c, &t) < 0) return -1;
        t->kind = TK_NAMED;
        t->id = id;
        t->value = value;
        memcpy(t->buf, formatted, sizeof formatted);
        return 0;
    }
    if (strcmp(word, "AP") == 0 || strcmp(word, "RP") == 0)
        return fail(c, "%s= is not supported (polar coordinates)", word);
    if (strlen(word) == 1) {
        if (!is_number_letter(word[0])) return fail(c, "%s", letter_refusal(word[0], buf));
        return fail(c, "%s= is not supported (write %s<number>)", word, word);
    }
    return fail(c, "%s= is not supported (settings the translator knows: SD, PW, PL, ADIS, ADISPOS, CR, RPL)", word);
}

static int cycle832(Ctx *c, size_t k, size_t *next) {
    const char *s = c->s;
    size_t end, i, j;
    double tolerance = 0.0;
    int kind = 1;
    char got[32], word[SIN_MAX_WORD + 2];
    Token *t = NULL;
    if (skip_parenthesis(c, k, "CYCLE832", &end) < 0) return -1;
    i = k + 1;
    while (i < end && is_blank(s[i])) i++;
    if (s[i] != ',' && s[i] != ')') {
        if (expression(c, &i, 1, "CYCLE832(", &tolerance) < 0) return -1;
        while (is_blank(s[i])) i++;
        if (s[i] != ',' && s[i] != ')') {
            shown(s[i], got);
            return fail(c, "',' or ')' after the tolerance of CYCLE832, got %s", got);
        }
    }
    if (!(isfinite(tolerance) && tolerance >= 0.0)) return fail(c, "a tolerance >= 0 in CYCLE832");
    if (s[i] == ',') {
        size_t length, m;
        int all_digits = 1;
        i++;
        while (is_blank(s[i])) i++;
        if (word_end(c, i, &j) < 0) return -1;
        upper_copy(s, i, j, word);
        length = j - i;
        for (m = 0; m < length; m++)
            if (!is_digit(word[m])) all_digits = 0;
        if (strcmp(word, "_OFF") == 0)
            kind = 0;
        else if (strcmp(word, "_FINISH") == 0 || strcmp(word, "_ORI_FINISH") == 0)
            kind = 1;
        else if (strcmp(word, "_SEMIFIN") == 0 || strcmp(word, "_ORI_SEMIFIN") == 0)
            kind = 2;
        else if (strcmp(word, "_ROUGH") == 0 || strcmp(word, "_ORI_ROUGH") == 0)
            kind = 3;
        else if (length > 0 && all_digits)
            kind = word[length - 1] - '0';
        else if (length > 0)
            return fail(c, "a machining type of CYCLE832 (_OFF, _ROUGH, _SEMIFIN, _FINISH or a number), got %s",
                        word);
    }
    if (push(c, &t) < 0) return -1;
    t->kind = TK_CYCLE832;
    t->value = kind != 0 ? tolerance : 0.0;
    *next = end;
    return 0;
}

static int proc(Ctx *c, size_t k, size_t *next) {
    size_t j, m;
    char name[SIN_MAX_WORD + 2];
    Token *t = NULL;
    if (word_end(c, k, &j) < 0) return -1;
    upper_copy(c->s, k, j, name);
    if (j == k || !is_letter(name[0])) return fail(c, "a subprogram name after PROC");
    if (j - k > SIN_NAME_LENGTH) return fail(c, "a subprogram name of at most %d characters", SIN_NAME_LENGTH);
    m = j;
    while (m < c->n && is_blank(c->s[m])) m++;
    if (m < c->n && c->s[m] == '(')
        return fail(c, "PROC %s is not supported with parameters (subprograms without parameters)", name);
    if (push(c, &t) < 0) return -1;
    t->kind = TK_PROC;
    copy_name(t->buf, sizeof t->buf, name);
    *next = j;
    return 0;
}

/* Tokens of the line; R assignments are carried out here, left to right. */
static int lex(Ctx *c) {
    const char *s = c->s;
    size_t n = c->n, i = 0, j, k, start;
    char buf[160], word[SIN_MAX_WORD + 2], what[2] = {0, 0};
    Token *t = NULL;
    double value;
    while (i < n) {
        char ch = s[i], letter;
        if (is_blank(ch)) {
            i++;
            continue;
        }
        if (ch == ';') break;
        if (ch == ':' && i + 1 < n && is_digit(s[i + 1])) {
            i++;
            if (number(c, &i, "':'", &value, &start) < 0 || push(c, &t) < 0) return -1;
            t->kind = TK_N;
            t->text = s + start;
            t->text_length = (int)(i - start);
            continue;
        }
        if (ch == '$') {
            if (word_end(c, i + 1, &j) < 0) return -1;
            upper_copy(s, i, j, word);
            return fail(c, "%s is not supported (system variables: use R0 to R99)", word);
        }
        if (!(is_letter(ch) || ch == '_')) {
            char got[32];
            shown(ch, got);
            return fail(c, "a word (address and value), a keyword, a comment (;) or the end of the line, got %s", got);
        }
        letter = upper(ch);
        what[0] = letter;
        if (i + 1 < n && (is_digit(s[i + 1]) || s[i + 1] == '.')) {
            j = i + 1;
            while (j < n && is_digit(s[j])) j++;
            k = j;
            while (k < n && is_blank(s[k])) k++;
            if (j > i + 1 && k < n && s[k] == '=') {
                int index = SIN_R_COUNT;
                char name[SIN_MAX_WORD + 2];
                if (j - i > SIN_MAX_WORD) return fail(c, "a word of at most %d characters", SIN_MAX_WORD);
                upper_copy(s, i, j, name);
                if (letter != 'R') return fail(c, "%s= is not supported (addresses with an extension)", name);
                if (j - i - 1 <= 3) {
                    size_t m;
                    index = 0;
                    for (m = i + 1; m < j; m++) index = index * 10 + (s[m] - '0');
                }
                if (index >= SIN_R_COUNT) return fail(c, "an R parameter R0 to R%d, got %s", SIN_R_COUNT - 1, name);
                i = k + 1;
                if (eval_value(c, &i, name, &value) < 0) return -1;
                c->st->r[index] = value;
                c->st->r_set[index] = 1;
                c->st->r_section[index] = c->st->section;
                continue;
            }
            if (letter == 'L' && j > i + 1) {
                if (j < n && is_name_char(s[j])) {
                    if (j + 1 - i > SIN_MAX_WORD) return fail(c, "a word of at most %d characters", SIN_MAX_WORD);
                    upper_copy(s, i, j + 1, word);
                    return fail(c, "%s... is not supported (a subprogram L<digits>)", word);
                }
                if (j - i > SIN_NAME_LENGTH)
                    return fail(c, "a subprogram name of at most %d characters", SIN_NAME_LENGTH);
                if (push(c, &t) < 0) return -1;
                t->kind = TK_CALL;
                upper_copy(s, i, j, t->buf);
                i = j;
                continue;
            }
            if (!is_number_letter(letter)) return fail(c, "%s", letter_refusal(letter, buf));
            i++;
            if (number(c, &i, what, &value, &start) < 0 || push(c, &t) < 0) return -1;
            t->kind = TK_W;
            t->letter = letter;
            t->value = value;
            t->text = s + start;
            t->text_length = (int)(i - start);
            continue;
        }
        if (word_end(c, i, &j) < 0) return -1;
        upper_copy(s, i, j, word);
        k = j;
        while (k < n && is_blank(s[k])) k++;
        if (j - i == 1 && k < n && (s[k] == '+' || s[k] == '-') && is_number_letter(word[0]) && k == j) {
            i = j;
            if (number(c, &i, word, &value, &start) < 0 || push(c, &t) < 0) return -1;
            t->kind = TK_W;
            t->letter = word[0];
            t->value = value;
            t->text = s + start;
            t->text_length = (int)(i - start);
            continue;
        }
        if (k < n && s[k] == '=') {
            i = k + 1;
            if (named(c, word, &i) < 0) return -1;
            continue;
        }
        if (k < n && s[k] == '(') {
            const char *reason;
            if (strcmp(word, "MSG") == 0 || strcmp(word, "WORKPIECE") == 0) {
                if (push(c, &t) < 0) return -1;
                t->kind = TK_NOTE;
                t->id = noted_index(word);
                if (skip_parenthesis(c, k, word, &i) < 0) return -1;
                continue;
            }
            if (strcmp(word, "CYCLE832") == 0) {
                if (cycle832(c, k, &i) < 0) return -1;
                continue;
            }
            reason = refused_reason(word);
            if (reason) return fail(c, "%s is not supported (%s)", word, reason);
            return fail(c, "%s is not supported (cycles and procedures with arguments: let the CAM post write their "
                           "moves)", word);
        }
        if (j < n && s[j] == ':' && is_letter(word[0])) {
            i = j + 1; /* a jump label (no GOTO is accepted: it has no effect) */
            continue;
        }
        if (strcmp(word, "CALL") == 0) {
            if (k < n && s[k] == '"') {
                const char *e = memchr(s + k + 1, '"', n - k - 1);
                size_t length;
                if (!e) return fail(c, "a closing '\"' after CALL \"");
                length = (size_t)(e - (s + k + 1));
                if (length > SIN_NAME_LENGTH)
                    return fail(c, "a subprogram name of at most %d characters", SIN_NAME_LENGTH);
                if (!control_free(s + k + 1, length)) return fail(c, "a subprogram name without control characters");
                if (push(c, &t) < 0) return -1;
                t->kind = TK_CALL;
                upper_copy(s, k + 1, k + 1 + length, t->buf);
                i = (size_t)(e - s) + 1;
                continue;
            }
            return fail(c, "CALL \"<subprogram name>\"");
        }
        if (strcmp(word, "PROC") == 0) {
            if (proc(c, k, &i) < 0) return -1;
            continue;
        }
        if (j - i == 1) {
            if (is_number_letter(word[0])) return fail(c, "a number after %s", word);
            return fail(c, "%s", letter_refusal(word[0], buf));
        }
        {
            int kw = in_list(word, KEYWORDS, K_COUNT), nt = noted_index(word);
            const char *reason;
            if (kw >= 0 || nt >= 0) {
                if (push(c, &t) < 0) return -1;
                t->kind = TK_K;
                t->id = kw >= 0 ? kw : K_COUNT + nt;
            } else if (subprogram_index(c->st, word) >= 0) {
                if (push(c, &t) < 0) return -1;
                t->kind = TK_CALL;
                copy_name(t->buf, sizeof t->buf, word);
            } else if ((reason = refused_reason(word)) != NULL) {
                return fail(c, "%s is not supported (%s)", word, reason);
            } else {
                return fail(c, "%s is not supported (a subprogram of this name in this file, a %%_N_%s_SPF section, "
                               "or a word the translator knows)", word, word);
            }
        }
        i = j;
    }
    return 0;
}

/* ---- translation ---- */

static const char *token_text(const Token *t, int *length) {
    if (t->text) {
        *length = t->text_length;
        return t->text;
    }
    *length = (int)strlen(t->buf);
    return t->buf;
}

static void add_note(SinState *st, int index) {
    size_t used;
    if (st->noted & (1ul << index)) return;
    st->noted |= 1ul << index;
    used = strlen(st->note);
    snprintf(st->note + used, sizeof st->note - used, "%s%s: %s: not modelled", used ? "; " : "", NOTED[index][0],
             NOTED[index][1]);
}

/* The core form of G<code> into `piece` ("" for an accepted, not modelled code). */
static int g_code(Ctx *c, int code, char piece[64]) {
    static const int plain[] = {0, 1, 2, 3, 4, 9, 17, 18, 19, 40, 53, 54, 55, 56, 57, 90, 91, 94, 95, 500};
    SinState *st = c->st;
    const char *need;
    size_t k;
    piece[0] = '\0';
    for (k = 0; k < sizeof plain / sizeof plain[0]; k++)
        if (code == plain[k]) {
            snprintf(piece, 64, "G%d", code);
            return 0;
        }
    if (code == 41 || code == 42) {
        if (st->edge_section != st->section)
            return fail(c, "D1 in this program section before G%d, without a subprogram call between (the tool here "
                           "depends on the calls)", code);
        if (st->edge != 1) return fail(c, "G%d with an active tool offset (D1 after the tool change)", code);
        snprintf(piece, 64, "G%d D%d", code, st->active);
        return 0;
    }
    if (code == 153) {
        snprintf(piece, 64, "G53");
        return 0;
    }
    if (code == 60 || code == 64) {
        st->blend = 0;
        snprintf(piece, 64, code == 60 ? "G61" : "G64");
        return 0;
    }
    if (code >= 641 && code <= 645) {
        char value[32];
        st->blend = 1;
        if (st->adis > 0.0) {
            if (format_value(c, st->adis, value) < 0) return -1;
            snprintf(piece, 64, "G64 P%s", value);
        } else {
            snprintf(piece, 64, "G64");
        }
        return 0;
    }
    if (code == 70 || code == 700 || code == 71 || code == 710) {
        snprintf(piece, 64, code == 70 || code == 700 ? "G20" : "G21");
        return 0;
    }
    if (code == 601 || code == 602 || code == 603 || code == 450 || code == 451) {
        char name[16];
        snprintf(name, sizeof name, "G%d", code);
        add_note(st, noted_index(name));
        return 0;
    }
    if (code == 58 || code == 59)
        need = "axial programmable offsets";
    else if (code >= 505 && code <= 599)
        need = "settable work offsets beyond G57";
    else if (code >= 110 && code <= 112)
        need = "polar coordinates";
    else
        need = "G codes the translator knows: G0-G4, G9, G17-G19, G40-G42, G53-G57, G60, G64, G641-G645, G70, "
               "G71, G90, G91, G94, G95, G153, G500, G700, G710";
    return fail(c, "G%d is not supported (%s)", code, need);
}

static int m_code(Ctx *c, int code, char piece[16]) {
    if ((code >= 0 && code <= 9) || code == 19 || code == 30) {
        snprintf(piece, 16, "M%d", code);
        return 0;
    }
    if (code == 17) {
        snprintf(piece, 16, "M99");
        return 0;
    }
    return fail(c, "M%d is not supported (M0-M9, M17, M19, M30)", code);
}

static void put_n(Out *o, const Token *t) {
    int length;
    const char *text = token_text(t, &length);
    put(o, "N%.*s", length, text);
}

static int frame(Ctx *c, int word, Out *o) {
    SinState *st = c->st;
    double values[3] = {0.0, 0.0, 0.0}, rpl = 0.0;
    int present[3] = {0, 0, 0}, a, clear = 0, any = 0, k;
    const char *name = KEYWORDS[word];
    for (k = 0; k < c->n_tokens; k++) {
        const Token *t = &c->tokens[k];
        int axis = t->kind == TK_W && t->letter && strchr("XYZ", t->letter) ? t->letter - 'X' : -1;
        if (t->kind == TK_N || (t->kind == TK_W && t->letter == 'N')) {
            put_n(o, t);
        } else if (axis >= 0 && !present[axis]) {
            present[axis] = 1;
            values[axis] = t->value;
        } else if (t->kind == TK_NAMED && t->id == NAMED_RPL && (word == K_ROT || word == K_AROT)) {
            rpl = t->value;
        } else if (!(t->kind == TK_K && t->id == word)) {
            return fail(c, "%s in a line of its own, with N and the axes X, Y, Z (frame instructions)", name);
        }
    }
    for (a = 0; a < 3; a++) any |= present[a];
    if (word == K_ATRANS && st->frame_section != st->section)
        return fail(c, "TRANS in this program section before ATRANS, without a subprogram call between (the frame "
                       "here depends on the calls)");
    if (word == K_TRANS || word == K_ATRANS) {
        for (a = 0; a < 3; a++)
            st->frame[a] = word == K_TRANS ? (present[a] ? values[a] : 0.0)
                                           : st->frame[a] + (present[a] ? values[a] : 0.0);
    } else if (word == K_ROT || word == K_AROT) {
        int nonzero = rpl != 0.0;
        for (a = 0; a < 3; a++)
            if (present[a] && values[a] != 0.0) nonzero = 1;
        if (nonzero) return fail(c, "%s with angles 0 (frame rotation is not modelled)", name);
        clear = word == K_ROT;
    } else if (word == K_SCALE || word == K_ASCALE) {
        for (a = 0; a < 3; a++)
            if (present[a] && values[a] != 1.0)
                return fail(c, "%s with factors 1 (frame scaling is not modelled)", name);
        clear = word == K_SCALE;
    } else {
        if (any) return fail(c, "%s without axes (mirroring is not modelled)", name);
        clear = word == K_MIRROR;
    }
    if (word == K_AROT || word == K_ASCALE || word == K_AMIRROR) return 0;
    if (clear) st->frame[0] = st->frame[1] = st->frame[2] = 0.0;
    st->frame_section = st->section;
    {
        char x[32], y[32], z[32];
        if (format_value(c, st->frame[0], x) < 0 || format_value(c, st->frame[1], y) < 0 ||
            format_value(c, st->frame[2], z) < 0)
            return -1;
        put(o, "G52 X%s Y%s Z%s", x, y, z);
    }
    return 0;
}

static int proc_line(Ctx *c, const char *name, const char *after_header, Out *o) {
    SinState *st = c->st;
    int k;
    for (k = 0; k < c->n_tokens; k++) {
        const Token *t = &c->tokens[k];
        if (!(t->kind == TK_N || (t->kind == TK_W && t->letter == 'N') || t->kind == TK_PROC ||
              (t->kind == TK_K && IS_PROC_ATTRIBUTE(t->id))))
            return fail(c, "PROC <name> in a line of its own");
    }
    if (st->spline_open)
        return fail(c, "the end of the B spline (a line with G0, G1, G2, G3, M2, M30, M17 or RET) before the next "
                       "program section");
    st->spline = 0;
    if (strcmp(name, after_header) != 0) {
        int index = register_subprogram(st, name);
        if (index < 0) return fail(c, "at most %d subprograms in one file", SIN_MAX_SUBPROGRAMS);
        st->section = 1 + index;
        put(o, "O%d", SIN_FIRST_SUBPROGRAM + index);
    }
    return 0;
}

static int call_number(Ctx *c, const char *name, int *number) {
    int index = subprogram_index(c->st, name);
    if (index < 0) return fail(c, "subprogram %s in this file (a %%_N_%s_SPF section)", name, name);
    *number = SIN_FIRST_SUBPROGRAM + index;
    return 0;
}

static int is_integer(double v) { return v == floor(v); }

static int line(Ctx *c, const char *after_header, Out *o) {
    SinState *st = c->st;
    const Token *named_tokens[NAMED_COUNT] = {0};
    int k, has_axes = 0, bspline = 0, ret = 0, calls = 0, motion = 0, closes = 0, g4 = 0, m6 = 0;
    int spline_point, opening, edge_set = 0, blend_set = 0, first_axis = 1, count = 0;
    int length;
    const char *text;
    for (k = 0; k < c->n_tokens; k++) {
        const Token *t = &c->tokens[k];
        if (t->kind == TK_K && IS_FRAME(t->id)) return frame(c, t->id, o);
    }
    for (k = 0; k < c->n_tokens; k++)
        if (c->tokens[k].kind == TK_PROC) return proc_line(c, c->tokens[k].buf, after_header, o);
    for (k = 0; k < c->n_tokens; k++) {
        const Token *t = &c->tokens[k];
        if (t->kind == TK_W && (t->letter == 'G' || t->letter == 'M')) {
            int code;
            if (!(t->value > -1e6 && t->value < 1e6 && is_integer(t->value))) {
                text = token_text(t, &length);
                return fail(c, "%c%.*s is not supported", t->letter, length, text);
            }
            code = (int)t->value;
            if (t->letter == 'G') {
                if (code >= 0 && code <= 3) motion = 1;
                if (code == 4) g4 = 1;
            } else {
                if (code == 2 || code == 17 || code == 30) closes = 1;
                if (code == 6) m6 = 1;
            }
        } else if (t->kind == TK_W && t->letter && strchr("XYZ", t->letter)) {
            has_axes = 1;
        } else if (t->kind == TK_NAMED) {
            named_tokens[t->id] = t;
        } else if (t->kind == TK_K) {
            if (t->id == K_BSPLINE) bspline = 1;
            if (t->id == K_RET) ret = 1;
            if (IS_PROC_ATTRIBUTE(t->id)) return fail(c, "%s is not supported (an attribute of a PROC line)",
                                                      KEYWORDS[t->id]);
        } else if (t->kind == TK_CALL) {
            calls++;
        }
    }
    if (calls > 1) return fail(c, "one subprogram call per line");
    if (named_tokens[NAMED_RPL]) return fail(c, "RPL= with ROT or AROT");
    closes = closes || motion || ret;
    if (st->spline_open && closes) {
        if (has_axes && !motion)
            return fail(c, "the end of the program or subprogram in a line after the last B spline point");
        put(o, "G5.3");
        st->spline_open = 0;
    }
    if (bspline && motion) return fail(c, "either BSPLINE or G0, G1, G2, G3 in a line (both select the motion)");
    if (closes) st->spline = 0;
    if (bspline) st->spline = 1;
    if (named_tokens[NAMED_SD]) {
        const Token *t = named_tokens[NAMED_SD];
        if (t->value != 2.0 && t->value != 3.0) return fail(c, "a B spline degree SD of 2 or 3, got SD=%s", t->buf);
        if (st->spline_open) return fail(c, "SD before the first point of the B spline");
        st->degree = (int)t->value;
    }
    for (k = 0; k < 2; k++) {
        int id = k == 0 ? NAMED_PW : NAMED_PL;
        if (named_tokens[id]) {
            if (!st->spline)
                return fail(c, "%s in BSPLINE mode (the %s of a B spline point)", NAMED[id],
                            k == 0 ? "weight" : "knot interval");
            if (!has_axes) return fail(c, "%s with the point (X, Y, Z) it belongs to", NAMED[id]);
        }
    }
    spline_point = st->spline && has_axes;
    opening = spline_point && !st->spline_open;
    if (g4 && has_axes) return fail(c, "G4 in a line of its own (with F, the dwell in seconds)");
    for (k = 0; k < c->n_tokens; k++) {
        const Token *t = &c->tokens[k];
        if (t->kind == TK_W && t->letter == 'T') {
            if (!(t->value >= 0.0 && t->value <= 2147483647.0 && is_integer(t->value))) {
                text = token_text(t, &length);
                return fail(c, "a tool number T of 0 to 2147483647, got T%.*s", length, text);
            }
            st->tool = (int)t->value;
        }
    }
    if (m6) {
        st->active = st->tool;
        st->active_section = st->section;
    }
    for (k = 0; k < c->n_tokens; k++) {
        const Token *t = &c->tokens[k];
        if (t->kind == TK_W && t->letter == 'D') {
            if (t->value != 0.0 && t->value != 1.0) {
                text = token_text(t, &length);
                return fail(c, "D%.*s is not supported (one cutting edge per tool: D1, or D0)", length, text);
            }
            if (t->value == 1.0 && st->active_section != st->section)
                return fail(c, "a tool change (T<n> M6) in this program section before D1, without a subprogram call "
                               "between (the tool here depends on the calls)");
            if (t->value == 1.0 && st->active == 0) return fail(c, "a tool change (T<n> M6) before D1");
            st->edge = (int)t->value;
            st->edge_section = st->section;
            edge_set = 1;
        }
    }
    if (named_tokens[NAMED_ADIS]) {
        const Token *t = named_tokens[NAMED_ADIS];
        if (!(t->value >= 0.0)) return fail(c, "ADIS >= 0, got ADIS=%s", t->buf);
        st->adis = t->value;
    }
    for (k = 0; k < c->n_tokens; k++) {
        const Token *t = &c->tokens[k];
        if (t->kind == TK_W && t->letter == 'P') {
            if (!calls) return fail(c, "P (the number of passes) with a subprogram call");
            if (!(t->value >= 1.0 && t->value <= 9999.0 && is_integer(t->value))) {
                text = token_text(t, &length);
                return fail(c, "a number of passes P of 1 to 9999, got P%.*s", length, text);
            }
            count = (int)t->value;
        }
    }
    for (k = 0; k < c->n_tokens; k++) {
        const Token *t = &c->tokens[k];
        text = token_text(t, &length);
        if (t->kind == TK_N) {
            put_n(o, t);
        } else if (t->kind == TK_W) {
            char letter = t->letter;
            if (letter == 'N') {
                put_n(o, t);
            } else if (letter == 'G') {
                char piece[64];
                int code = (int)t->value;
                if (g_code(c, code, piece) < 0) return -1;
                if (piece[0]) put(o, "%s", piece);
                blend_set = blend_set || (code >= 641 && code <= 645);
            } else if (letter == 'M') {
                char piece[16];
                if (m_code(c, (int)t->value, piece) < 0) return -1;
                put(o, "%s", piece);
            } else if (letter == 'X' || letter == 'Y' || letter == 'Z') {
                if (opening && first_axis) put(o, "G5.2 L%d", st->degree + 1);
                first_axis = 0;
                put(o, "%c%.*s", letter, length, text);
            } else if (letter == 'I' || letter == 'J' || letter == 'K') {
                if (st->spline) return fail(c, "%c is not supported in BSPLINE mode (arc words)", letter);
                put(o, "%c%.*s", letter, length, text);
            } else if (letter == 'F') {
                put(o, "%c%.*s", g4 ? 'P' : 'F', length, text);
            } else if (letter == 'S') {
                if (g4) return fail(c, "G4 S is not supported (dwell in spindle revolutions: program G4 F<s>)");
                put(o, "S%.*s", length, text);
            } else if (letter == 'T') {
                put(o, "T%d", (int)t->value);
            } else if (letter == 'D') {
                if (t->value == 1.0)
                    put(o, "G43 H%d", st->active);
                else
                    put(o, "G49");
            }
        } else if (t->kind == TK_NAMED) {
            if (t->id == NAMED_CR) {
                if (st->spline) return fail(c, "CR is not supported in BSPLINE mode (arc words)");
                put(o, "R%s", t->buf);
            } else if (t->id == NAMED_ADIS) {
                if (st->blend && !blend_set) {
                    if (t->value > 0.0)
                        put(o, "G64 P%s", t->buf);
                    else
                        put(o, "G64");
                }
            } else if (t->id == NAMED_ADISPOS) {
                add_note(st, noted_index("ADISPOS"));
            }
        } else if (t->kind == TK_K) {
            if (t->id == K_RET)
                put(o, "M99");
            else if (t->id == K_SUPA)
                put(o, "G53");
            else if (t->id >= K_COUNT)
                add_note(st, t->id - K_COUNT);
        } else if (t->kind == TK_NOTE) {
            add_note(st, t->id);
        } else if (t->kind == TK_CALL) {
            int number = 0;
            if (st->spline)
                return fail(c, "the end of the B spline (G0, G1, G2, G3) before a subprogram call (the called "
                               "program's points would continue the spline)");
            if (call_number(c, t->buf, &number) < 0) return -1;
            st->frame_section = st->active_section = st->edge_section = -1;
            if (count)
                put(o, "M98 P%d L%d", number, count);
            else
                put(o, "M98 P%d", number);
        } else if (t->kind == TK_CYCLE832) {
            if (t->value > 0.0) {
                char value[32];
                if (format_value(c, t->value, value) < 0) return -1;
                put(o, "G64 P%s", value);
            } else {
                put(o, "G64");
            }
            st->blend = 0;
        }
    }
    if (spline_point) {
        const Token *pw = named_tokens[NAMED_PW], *pl = named_tokens[NAMED_PL];
        st->spline_open = 1;
        if (pw) {
            if (!(pw->value > 0.0)) return fail(c, "a point weight PW > 0, got PW=%s", pw->buf);
            put(o, "P%s", pw->buf);
        }
        if (pl) {
            if (!(pl->value > 0.0)) return fail(c, "a knot interval PL > 0, got PL=%s", pl->buf);
            put(o, "K%s", pl->buf);
        }
    }
    if (m6 && st->edge == 1 && st->edge_section == st->section && !edge_set) put(o, "G43 H%d", st->active);
    return 0;
}

static int header(Ctx *c, size_t i, Out *o) {
    SinState *st = c->st;
    const char *s = c->s + i;
    size_t n = c->n - i, k;
    const char *semicolon = memchr(s, ';', n);
    char name[SIN_MAX_OUTPUT];
    if (semicolon) n = (size_t)(semicolon - s);
    while (n > 0 && is_blank(s[n - 1])) n--;
    if (n == 1) return 0; /* "%" */
    if (n > 8 && upper(s[1]) == '_' && upper(s[2]) == 'N' && s[3] == '_' && s[n - 4] == '_' &&
        ((upper(s[n - 3]) == 'M' && upper(s[n - 2]) == 'P' && upper(s[n - 1]) == 'F') ||
         (upper(s[n - 3]) == 'S' && upper(s[n - 2]) == 'P' && upper(s[n - 1]) == 'F')) &&
        s[0] == '%') {
        size_t length = n - 8;
        int ok = length <= SIN_NAME_LENGTH && is_letter(s[4]);
        int main_program = upper(s[n - 3]) == 'M';
        for (k = 0; k < length; k++)
            if (!is_name_char(s[4 + k])) ok = 0;
        if (!ok)
            return fail(c, "a program name of at most %d letters, digits and _ (starting with a letter)",
                        SIN_NAME_LENGTH);
        if (st->spline_open)
            return fail(c, "the end of the B spline (a line with G0, G1, G2, G3, M2, M30, M17 or RET) before the next "
                           "program section");
        upper_copy(s, 4, 4 + length, name);
        st->spline = 0;
        st->after_header[0] = '\0';
        if (main_program) {
            st->section = 0;
            return 0;
        }
        {
            int index = register_subprogram(st, name);
            if (index < 0) return fail(c, "at most %d subprograms in one file", SIN_MAX_SUBPROGRAMS);
            st->section = 1 + index;
            copy_name(st->after_header, sizeof st->after_header, name);
            put(o, "O%d", SIN_FIRST_SUBPROGRAM + index);
        }
        return 0;
    }
    return fail(c, "a section header %%_N_<name>_MPF or %%_N_<name>_SPF, or %% alone");
}

void sin_init(SinState *state, const GcTool *tools, size_t n_tools) {
    memset(state, 0, sizeof *state);
    state->tools = tools;
    state->n_tools = tools ? n_tools : 0;
    state->degree = 3;
}

void sin_prescan(SinState *state, const char *text, size_t length) {
    size_t start = 0;
    while (start < length) {
        const char *s = text + start, *nl = memchr(s, '\n', length - start), *semicolon;
        size_t n = nl ? (size_t)(nl - s) : length - start, a = 0, b, name_start = 0, name_length = 0, k;
        start += n + 1;
        semicolon = memchr(s, ';', n);
        b = semicolon ? (size_t)(semicolon - s) : n;
        while (a < b && (is_blank(s[a]) || s[a] == '\r')) a++;
        while (b > a && (is_blank(s[b - 1]) || s[b - 1] == '\r')) b--;
        if (b - a >= 8 && s[a] == '%' && s[a + 1] == '_' && upper(s[a + 2]) == 'N' && s[a + 3] == '_' &&
            s[b - 4] == '_' && upper(s[b - 3]) == 'S' && upper(s[b - 2]) == 'P' && upper(s[b - 1]) == 'F') {
            name_start = a + 4;
            name_length = b - a - 8;
        } else if (b - a >= 5 && upper(s[a]) == 'P' && upper(s[a + 1]) == 'R' && upper(s[a + 2]) == 'O' &&
                   upper(s[a + 3]) == 'C' && is_blank(s[a + 4])) {
            size_t j = a + 5;
            while (j < b && is_blank(s[j])) j++;
            name_start = j;
            while (j < b && is_name_char(s[j])) j++;
            name_length = j - name_start;
        }
        if (name_length > 0 && name_length <= SIN_NAME_LENGTH && is_letter(s[name_start])) {
            char name[SIN_NAME_LENGTH + 1];
            int ok = 1;
            for (k = 0; k < name_length; k++)
                if (!is_name_char(s[name_start + k])) ok = 0;
            if (ok) {
                upper_copy(s, name_start, name_start + name_length, name);
                register_subprogram(state, name);
            }
        }
    }
}

int sin_translate_line(SinState *state, const char *text, size_t length, char *out, size_t out_size, char *expected,
                       size_t expected_size) {
    Ctx c;
    Out o;
    size_t i = 0;
    char after_header[SIN_NAME_LENGTH + 1];
    int status;
    c.st = state;
    c.s = text;
    c.expected = expected;
    c.expected_size = expected_size;
    c.n_tokens = 0;
    o.total = 0;
    o.buf[0] = '\0';
    state->note[0] = '\0';
    if (out_size > 0) out[0] = '\0';
    while (length > 0 && text[length - 1] == '\r') length--;
    c.n = length;
    while (i < length && is_blank(text[i])) i++;
    if (i >= length || text[i] == ';' || text[i] == '/') return 0;
    if (text[i] == '%') {
        status = header(&c, i, &o);
    } else {
        if (lex(&c) < 0) {
            state->note[0] = '\0';
            return -1;
        }
        if (c.n_tokens == 0) return 0;
        memcpy(after_header, state->after_header, sizeof after_header);
        state->after_header[0] = '\0';
        status = line(&c, after_header, &o);
    }
    if (status < 0) {
        state->note[0] = '\0';
        return -1;
    }
    if (o.total > SIN_MAX_OUTPUT || o.total >= out_size)
    {
        state->note[0] = '\0';
        return fail(&c, "a translated line of at most %d characters", SIN_MAX_OUTPUT);
    }
    memcpy(out, o.buf, o.total + 1);
    return 0;
}

int sin_finish(const SinState *state, char *expected, size_t expected_size) {
    if (!state->spline_open) return 0;
    if (expected_size > 0)
        snprintf(expected, expected_size, "the end of the B spline (a line with G0, G1, G2, G3, M2, M30, M17 or RET) "
                                          "before the end of the program");
    return -1;
}
