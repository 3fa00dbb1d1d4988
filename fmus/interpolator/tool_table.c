/* Tool table reader: LinuxCNC's format, one tool per line, with the geometry LinuxCNC has no column for as
 * key=value in the comment; the same checks and messages as models/interpolator/tool_table.py. Numbers are read
 * as the part program's (gc_read_number), not by strtod, whose decimal point follows the host's locale. */
#include "tool_table.h"

#include "gcode_number.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* The whole of s[0..n) as a plain decimal number (the part program's reader); -1 otherwise. */
static int read_number(const char *s, size_t n, double *value) {
    size_t i = 0;
    return gc_read_number(s, n, &i, value) == NUMBER_OK && i == n ? 0 : -1;
}

typedef struct {
    const char *text;
    size_t length;
    const char *file;
    size_t line;
    char *error;
    size_t error_size;
} Where;

static int fail(const Where *w, const char *expected) {
    gc_line_error(w->text, w->length, w->file, w->line, expected, w->error, w->error_size);
    return -1;
}

static int is_blank(char c) { return c == ' ' || c == '\t'; }

/* The next token of s[*i..n) separated by blanks and tabs; 0 when none is left. */
static int next_token(const char *s, size_t n, size_t *i, size_t *start, size_t *end) {
    while (*i < n && is_blank(s[*i])) (*i)++;
    if (*i >= n) return 0;
    *start = *i;
    while (*i < n && !is_blank(s[*i])) (*i)++;
    *end = *i;
    return 1;
}

enum { KEY_CORNER, KEY_FLUTES, KEY_HELIX, KEY_STICK_OUT, KEY_NAME, KEYS };
static const char *const KEY_NAMES[KEYS] = {"corner_radius", "flutes", "helix", "stick_out", "name"};

static int parse_line(const Where *w, const char *s, size_t n, GcTool *tools, size_t *n_tools) {
    static const char WORDS[] = "TPXYZABCUVWDIJQ";
    double values[26];
    int present[26] = {0};
    const char *extra[KEYS] = {0};
    size_t extra_length[KEYS] = {0};
    double geometry[4] = {0.0, 0.0, 0.0, 0.0};
    size_t body = 0, i = 0, a, b, k;
    char message[256];
    GcTool *tool;
    double t, diameter;
    int any = 0;
    while (body < n && s[body] != ';') body++;
    while (next_token(s, body, &i, &a, &b)) {
        char c = s[a];
        char letter = (char)(c >= 'a' && c <= 'z' ? c - 'a' + 'A' : c);
        double value;
        if (!strchr(WORDS, letter) || letter == '\0') {
            snprintf(message, sizeof message, "a tool table word T, P, X, Y, Z, A, B, C, U, V, W, D, I, J, Q (letter "
                     "and number), got '%.*s'", (int)(b - a > 40 ? 40 : b - a), s + a);
            return fail(w, message);
        }
        if (read_number(s + a + 1, b - a - 1, &value) != 0) {
            snprintf(message, sizeof message, "a number after '%c', got '%.*s'", letter,
                     (int)(b - a > 40 ? 40 : b - a), s + a);
            return fail(w, message);
        }
        if (present[letter - 'A']) {
            snprintf(message, sizeof message, "one %c word per tool", letter);
            return fail(w, message);
        }
        if (fabs(value) > MAX_TOOL_VALUE) {
            snprintf(message, sizeof message, "a value of magnitude at most %g after '%c', got '%.*s'", MAX_TOOL_VALUE,
                     letter, (int)(b - a > 40 ? 40 : b - a), s + a);
            return fail(w, message);
        }
        present[letter - 'A'] = 1;
        values[letter - 'A'] = value;
        any = 1;
    }
    if (!any) return 0;
    if (!present['T' - 'A']) return fail(w, "the tool number T");
    t = values['T' - 'A'];
    if (t != floor(t) || t < 1.0 || t > MAX_TOOL_NUMBER) {
        snprintf(message, sizeof message, "a whole tool number T of 1 to %d", MAX_TOOL_NUMBER);
        return fail(w, message);
    }
    for (k = 0; k < *n_tools; k++) {
        if (tools[k].number == (int)t) {
            snprintf(message, sizeof message, "tool T%d once in the table", (int)t);
            return fail(w, message);
        }
    }
    if (*n_tools >= MAX_TOOLS) {
        snprintf(message, sizeof message, "at most %d tools", MAX_TOOLS);
        return fail(w, message);
    }
    diameter = present['D' - 'A'] ? values['D' - 'A'] : 0.0;
    if (diameter < 0.0) return fail(w, "a diameter D >= 0");
    i = body < n ? body + 1 : n;
    while (next_token(s, n, &i, &a, &b)) {
        size_t eq = a;
        while (eq < b && s[eq] != '=') eq++;
        if (eq == b) continue;
        for (k = 0; k < KEYS; k++) {
            if (strlen(KEY_NAMES[k]) == eq - a && memcmp(KEY_NAMES[k], s + a, eq - a) == 0) break;
        }
        if (k == KEYS) continue;
        if (extra[k]) {
            snprintf(message, sizeof message, "one %s= per tool", KEY_NAMES[k]);
            return fail(w, message);
        }
        extra[k] = s + eq + 1;
        extra_length[k] = b - eq - 1;
    }
    for (k = 0; k < KEY_NAME; k++) {
        if (extra[k] && (read_number(extra[k], extra_length[k], &geometry[k]) != 0 ||
                         fabs(geometry[k]) > MAX_TOOL_VALUE)) {
            snprintf(message, sizeof message, "a number of magnitude at most %g after %s=, got '%.*s'", MAX_TOOL_VALUE,
                     KEY_NAMES[k], (int)(extra_length[k] > 40 ? 40 : extra_length[k]), extra[k]);
            return fail(w, message);
        }
    }
    if (geometry[KEY_CORNER] < 0.0 || geometry[KEY_CORNER] > 0.5 * diameter) {
        snprintf(message, sizeof message, "a corner_radius of 0 to half the diameter (%g mm), got %.*s",
                 0.5 * diameter, (int)(extra_length[KEY_CORNER] > 40 ? 40 : extra_length[KEY_CORNER]),
                 extra[KEY_CORNER]);
        return fail(w, message);
    }
    if (geometry[KEY_FLUTES] < 0.0 || geometry[KEY_FLUTES] != floor(geometry[KEY_FLUTES])) {
        snprintf(message, sizeof message, "a whole number of flutes >= 0, got %.*s",
                 (int)(extra_length[KEY_FLUTES] > 40 ? 40 : extra_length[KEY_FLUTES]), extra[KEY_FLUTES]);
        return fail(w, message);
    }
    if (!(geometry[KEY_HELIX] >= 0.0 && geometry[KEY_HELIX] < 90.0)) {
        snprintf(message, sizeof message, "a helix angle of 0 to less than 90 degrees, got %.*s",
                 (int)(extra_length[KEY_HELIX] > 40 ? 40 : extra_length[KEY_HELIX]), extra[KEY_HELIX]);
        return fail(w, message);
    }
    if (geometry[KEY_STICK_OUT] < 0.0) {
        snprintf(message, sizeof message, "a stick_out >= 0, got %.*s",
                 (int)(extra_length[KEY_STICK_OUT] > 40 ? 40 : extra_length[KEY_STICK_OUT]), extra[KEY_STICK_OUT]);
        return fail(w, message);
    }
    if (extra[KEY_NAME] &&
        (extra_length[KEY_NAME] > MAX_TOOL_NAME || memchr(extra[KEY_NAME], '"', extra_length[KEY_NAME]))) {
        snprintf(message, sizeof message, "a name of at most %d characters without '\"'", MAX_TOOL_NAME);
        return fail(w, message);
    }
    if (extra[KEY_NAME] && extra_length[KEY_NAME] > 0) {
        for (k = 0; k < *n_tools; k++) {
            if (strlen(tools[k].name) == extra_length[KEY_NAME] &&
                memcmp(tools[k].name, extra[KEY_NAME], extra_length[KEY_NAME]) == 0) {
                snprintf(message, sizeof message, "the name %s once in the table", tools[k].name);
                return fail(w, message);
            }
        }
    }
    tool = &tools[(*n_tools)++];
    memset(tool, 0, sizeof *tool);
    tool->number = (int)t;
    if (extra[KEY_NAME]) memcpy(tool->name, extra[KEY_NAME], extra_length[KEY_NAME]);
    tool->diameter = diameter / 1000.0;
    tool->corner_radius = geometry[KEY_CORNER] / 1000.0;
    tool->length = (present['Z' - 'A'] ? values['Z' - 'A'] : 0.0) / 1000.0;
    tool->stick_out = geometry[KEY_STICK_OUT] / 1000.0;
    tool->helix = geometry[KEY_HELIX] * (PI / 180.0);
    tool->flutes = (int)geometry[KEY_FLUTES];
    return 0;
}

int tool_table_parse(const char *text, size_t length, const char *file, GcTool **tools, size_t *n_tools, char *error,
                     size_t error_size) {
    size_t start = 0, i, lines = 1;
    Where w;
    GcTool *table;
    *tools = NULL;
    *n_tools = 0;
    if (error_size) error[0] = '\0';
    for (i = 0; i < length; i++) lines += text[i] == '\n';
    table = malloc((lines < MAX_TOOLS ? lines : MAX_TOOLS) * sizeof *table);
    if (!table) {
        snprintf(error, error_size, "%s: out of memory for the tool table", file);
        return -1;
    }
    w.text = text, w.length = length, w.file = file, w.line = 0, w.error = error, w.error_size = error_size;
    for (i = 0; i <= length; i++) {
        if (i == length || text[i] == '\n') {
            size_t n = i - start;
            if (n > 0 && text[start + n - 1] == '\r') n--;
            w.line++;
            if (parse_line(&w, text + start, n, table, n_tools) != 0) {
                free(table);
                *n_tools = 0;
                return -1;
            }
            start = i + 1;
        }
    }
    if (*n_tools == 0) {
        free(table);
        table = NULL;
    }
    *tools = table;
    return 0;
}

const GcTool *tool_table_find(const GcTool *tools, size_t n_tools, int number) {
    size_t k;
    for (k = 0; k < n_tools; k++)
        if (tools[k].number == number) return &tools[k];
    return NULL;
}
