/* Test driver of the Sinumerik translator (fmus/interpolator/sinumerik.c): translates every line of a program
 * file as the parser does (prescan of the whole text, then line by line, then sin_finish) and prints one record
 * per line, which tests/test_interpolator_sinumerik.py compares byte for byte with the Python reference
 * (models/interpolator/sinumerik.py):
 *   "<line>\t0\t<translation>\t<note>"  or  "<line>\t-1\t<expected>"   ... then "end\t0" or "end\t-1\t<expected>"
 * Errors do not stop the run: the next line is translated with the state as the failed line left it.
 * Usage: sinumerik_translate <program file> [<tool number>=<tool name> ...] */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "sinumerik.h"

#define DRIVER_TOOLS 64

int main(int argc, char **argv) {
    FILE *f;
    char *text;
    long size;
    size_t length, start = 0, line = 1;
    GcTool tools[DRIVER_TOOLS];
    size_t n_tools = 0;
    int k;
    SinState *state;
    char out[SIN_MAX_OUTPUT + 1], expected[1024];
    if (argc < 2) {
        fprintf(stderr, "usage: %s <program file> [<number>=<name> ...]\n", argv[0]);
        return 2;
    }
    for (k = 2; k < argc && n_tools < DRIVER_TOOLS; k++) {
        const char *eq = strchr(argv[k], '=');
        memset(&tools[n_tools], 0, sizeof tools[n_tools]);
        if (!eq) return 2;
        tools[n_tools].number = atoi(argv[k]);
        strncpy(tools[n_tools].name, eq + 1, sizeof tools[n_tools].name - 1);
        n_tools++;
    }
    f = fopen(argv[1], "rb");
    if (!f) return 2;
    fseek(f, 0, SEEK_END);
    size = ftell(f);
    fseek(f, 0, SEEK_SET);
    text = malloc((size_t)size + 1);
    if (!text || fread(text, 1, (size_t)size, f) != (size_t)size) return 2;
    fclose(f);
    length = (size_t)size;
    state = malloc(sizeof *state);
    if (!state) return 2;
    sin_init(state, tools, n_tools);
    sin_prescan(state, text, length);
    while (start <= length) {
        const char *s = text + start, *nl = memchr(s, '\n', length - start);
        size_t n = nl ? (size_t)(nl - s) : length - start;
        if (sin_translate_line(state, s, n, out, sizeof out, expected, sizeof expected) == 0)
            printf("%zu\t0\t%s\t%s\n", line, out, state->note);
        else
            printf("%zu\t-1\t%s\n", line, expected);
        start += n + 1;
        line++;
    }
    if (sin_finish(state, expected, sizeof expected) == 0)
        printf("end\t0\n");
    else
        printf("end\t-1\t%s\n", expected);
    free(state);
    free(text);
    return 0;
}
