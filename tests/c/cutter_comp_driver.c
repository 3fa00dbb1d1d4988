/* Test driver of the cutter compensation stage (fmus/interpolator/cutter_comp.c), used by
 * tests/test_interpolator_cutter_comp.py to compare the C moves with the Python reference bit for bit.
 *
 *   cutter_comp_driver <moves file> <program text file> <file name for messages>
 *
 * The moves file: the program's start position (3 numbers), then one move per line, the GcMove fields in the
 * order of MOVE_FIELDS below (numbers as strtod reads them: hex floats are exact). Prints "ok <n>" and the
 * compensated moves in the same format (doubles as %a), or "error <message>". Exit status 0 either way, 2 on
 * unreadable input. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "cutter_comp.h"

/* kind line block start[3] end[3] offset[3] feed spindle spindle_on center[3] axes[3] theta0 sweep r0 r1 height
 * curve u0 u1 tool coolant exact_stop dwell tolerance comp comp_radius */
#define MOVE_FIELDS 36

static char *read_file(const char *path, size_t *length) {
    FILE *f = fopen(path, "rb");
    char *text = NULL;
    size_t n = 0, cap = 0, got;
    if (!f) return NULL;
    for (;;) {
        if (n + 4096 + 1 > cap) {
            char *t;
            cap = 2 * cap + 8192;
            t = realloc(text, cap);
            if (!t) {
                free(text);
                fclose(f);
                return NULL;
            }
            text = t;
        }
        got = fread(text + n, 1, 4096, f);
        n += got;
        if (got == 0) break;
    }
    fclose(f);
    text[n] = '\0';
    *length = n;
    return text;
}

static int to_int(double v) { return (int)v; }

static int parse_moves(char *text, GcProgram *program) {
    char *p = text, *end;
    double v[MOVE_FIELDS];
    int i;
    for (i = 0; i < 3; i++) {
        program->start[i] = strtod(p, &end);
        if (end == p) return -1;
        p = end;
    }
    for (;;) {
        GcMove *m;
        for (i = 0; i < MOVE_FIELDS; i++) {
            v[i] = strtod(p, &end);
            if (end == p) break;
            p = end;
        }
        if (i == 0) return 0;
        if (i < MOVE_FIELDS) return -1;
        if (program->n_moves == program->cap_moves) {
            size_t cap = program->cap_moves ? 2 * program->cap_moves : 16;
            GcMove *grown = realloc(program->moves, cap * sizeof *grown);
            if (!grown) return -1;
            program->moves = grown;
            program->cap_moves = cap;
        }
        m = &program->moves[program->n_moves++];
        memset(m, 0, sizeof *m);
        m->kind = to_int(v[0]), m->line = to_int(v[1]), m->block = to_int(v[2]);
        for (i = 0; i < 3; i++) m->start[i] = v[3 + i], m->end[i] = v[6 + i], m->offset[i] = v[9 + i];
        m->feed = v[12], m->spindle = v[13], m->spindle_on = to_int(v[14]);
        for (i = 0; i < 3; i++) m->center[i] = v[15 + i], m->axes[i] = to_int(v[18 + i]);
        m->theta0 = v[21], m->sweep = v[22], m->r0 = v[23], m->r1 = v[24], m->height = v[25];
        m->curve = to_int(v[26]), m->u0 = v[27], m->u1 = v[28];
        m->tool = to_int(v[29]), m->coolant = to_int(v[30]), m->exact_stop = to_int(v[31]);
        m->dwell = v[32], m->tolerance = v[33], m->comp = to_int(v[34]), m->comp_radius = v[35];
    }
}

static void print_move(const GcMove *m) {
    int i;
    printf("%d %d %d", m->kind, m->line, m->block);
    for (i = 0; i < 3; i++) printf(" %a", m->start[i]);
    for (i = 0; i < 3; i++) printf(" %a", m->end[i]);
    for (i = 0; i < 3; i++) printf(" %a", m->offset[i]);
    printf(" %a %a %d", m->feed, m->spindle, m->spindle_on);
    for (i = 0; i < 3; i++) printf(" %a", m->center[i]);
    for (i = 0; i < 3; i++) printf(" %d", m->axes[i]);
    printf(" %a %a %a %a %a %d %a %a", m->theta0, m->sweep, m->r0, m->r1, m->height, m->curve, m->u0, m->u1);
    printf(" %d %d %d %a %a %d %a\n", m->tool, m->coolant, m->exact_stop, m->dwell, m->tolerance, m->comp,
           m->comp_radius);
}

int main(int argc, char **argv) {
    GcProgram program;
    char *moves_text, *text, error[1024];
    size_t moves_length, length, k;
    if (argc != 4) {
        fprintf(stderr, "usage: %s <moves file> <program text file> <file name>\n", argv[0]);
        return 2;
    }
    memset(&program, 0, sizeof program);
    moves_text = read_file(argv[1], &moves_length);
    text = read_file(argv[2], &length);
    if (!moves_text || !text || parse_moves(moves_text, &program) != 0) {
        fprintf(stderr, "unreadable input\n");
        free(moves_text);
        free(text);
        free(program.moves);
        return 2;
    }
    if (cutter_compensate(&program, text, length, argv[3], error, sizeof error) != 0) {
        printf("error %s\n", error);
    } else {
        printf("ok %zu\n", program.n_moves);
        for (k = 0; k < program.n_moves; k++) print_move(&program.moves[k]);
    }
    free(program.moves);
    free(moves_text);
    free(text);
    return 0;
}
