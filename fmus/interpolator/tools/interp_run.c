/* Standalone driver of the interpolator engine (the FMU's C code without the FMI wrapper):
 *
 *   interp_run [--param name=value ...] [--dialect fanuc|linuxcnc|sinumerik] [--tool-table tool.tbl]
 *              [--csv out.csv] [--repeat N] [--override x] [--timing] [--until t] program.nc
 *
 * Parameters take the FMU's variable names and SI values (period, method, corrector_predictor, corrector_tolerance,
 * max_feed, rapid_feed, acceleration, jerk, centripetal_acceleration, chord_error, axis_acceleration_x..,
 * axis_jerk_x.., start_x.., g54_x..g59_z, rbf_*, lookahead_blocks). Runs the program to its end, one tick per
 * interpolation period; --csv writes every point (tick, t, x, y, z, feed, path_acceleration, u, line, move, s,
 * x_program, y_program, z_program, vx, vy, vz); --repeat N times the tick loop N times (parsing and scheduling
 * excluded) and prints the median cost per interpolation point; --timing prints the seconds of the initialisation
 * (parsing and path, the heap, the first plan), of the run, and of the longest tick (the re-plans of the look-ahead
 * window happen in ticks), and the peak resident memory (Linux; -1 elsewhere); --until t stops the run after t
 * seconds of machine time. Parameters not given keep the model definition's start values (model_set_start_values);
 * --param goes through the FMU's generated variable table. Built by CMake from the same sources as the FMU
 * (fmus/interpolator/interpolator.cmake). */
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "../interp_settings.h"
#include "../tool_table.h"

/* Sets a parameter by its FMU name through the generated variable table (name, type, offset in ModelVariables),
 * as the FMU's set functions do (without their range checks). */
static int set_param(ModelVariables *v, const char *assignment) {
    char name[64], *end;
    const char *eq = strchr(assignment, '=');
    double value;
    unsigned int i;
    if (!eq || (size_t)(eq - assignment) >= sizeof name) return -1;
    memcpy(name, assignment, (size_t)(eq - assignment));
    name[eq - assignment] = '\0';
    value = strtod(eq + 1, &end);
    if (*end) return -1;
    for (i = 0; i < MODEL_VARIABLE_COUNT; i++) {
        const FmuVariable *row = &MODEL_VARIABLE_TABLE[i];
        char *field = (char *)v + row->offset;
        if (!row->name || row->causality != FMU_PARAMETER || strcmp(row->name, name) != 0) continue;
        if (row->type == FMU_FLOAT64) {
            memcpy(field, &value, sizeof value);
        } else if (row->type == FMU_INT32) {
            int32_t x = (int32_t)value;
            memcpy(field, &x, sizeof x);
        } else if (row->type == FMU_BOOLEAN) {
            bool x = value != 0.0;
            memcpy(field, &x, sizeof x);
        } else {
            return -1; /* the program is the command's argument */
        }
        return 0;
    }
    return -1;
}

static char *read_all(const char *path, size_t *length) {
    FILE *f = fopen(path, "rb");
    char *text;
    long n;
    if (!f) return NULL;
    fseek(f, 0, SEEK_END);
    n = ftell(f);
    fseek(f, 0, SEEK_SET);
    text = malloc((size_t)n + 1);
    if (text && fread(text, 1, (size_t)n, f) != (size_t)n) {
        free(text);
        text = NULL;
    }
    fclose(f);
    if (text) text[n] = '\0', *length = (size_t)n;
    return text;
}

/* The process's peak resident memory in MB (VmHWM of /proc/self/status: this program's own, not the pre-exec
 * image's that getrusage would include); -1 where there is no such file. */
static double peak_mb(void) {
    char line[256];
    double kb = -1.0;
    FILE *f = fopen("/proc/self/status", "r");
    if (!f) return -1.0;
    while (fgets(line, sizeof line, f))
        if (strncmp(line, "VmHWM:", 6) == 0) kb = atof(line + 6);
    fclose(f);
    return kb < 0.0 ? -1.0 : kb / 1024.0;
}

static double now_ns(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec * 1e9 + (double)ts.tv_nsec;
}

static int compare(const void *a, const void *b) {
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

int main(int argc, char **argv) {
    InterpSettings settings;
    InterpPrepared prepared;
    InterpLayout layout;
    InterpState state;
    const char *program = NULL, *csv = NULL, *dialect = "fanuc", *table = NULL;
    GcTool *tools = NULL;
    size_t n_tools = 0;
    ModelVariables variables;
    int repeat = 0, k, timing = 0;
    double t_begin = now_ns(), t_prepared = 0.0, t_installed = 0.0, t_planned = 0.0, longest = 0.0;
    double override = 1.0, until = 0.0, *heap, *costs = NULL;
    size_t length = 0;
    char *text, error[1024];
    FILE *out = NULL;
    model_set_start_values(&variables); /* the model definition's defaults */
    for (k = 1; k < argc; k++) {
        if (strcmp(argv[k], "--param") == 0 && k + 1 < argc) {
            if (set_param(&variables, argv[++k]) != 0) {
                fprintf(stderr, "interp_run: bad --param %s\n", argv[k]);
                return 2;
            }
        } else if (strcmp(argv[k], "--dialect") == 0 && k + 1 < argc) {
            dialect = argv[++k];
        } else if (strcmp(argv[k], "--tool-table") == 0 && k + 1 < argc) {
            table = argv[++k];
        } else if (strcmp(argv[k], "--csv") == 0 && k + 1 < argc) {
            csv = argv[++k];
        } else if (strcmp(argv[k], "--repeat") == 0 && k + 1 < argc) {
            repeat = atoi(argv[++k]);
        } else if (strcmp(argv[k], "--override") == 0 && k + 1 < argc) {
            override = atof(argv[++k]);
        } else if (strcmp(argv[k], "--until") == 0 && k + 1 < argc) {
            until = atof(argv[++k]);
        } else if (strcmp(argv[k], "--timing") == 0) {
            timing = 1;
        } else if (argv[k][0] != '-' && !program) {
            program = argv[k];
        } else {
            fprintf(stderr, "usage: interp_run [--param name=value ...] [--dialect fanuc|linuxcnc|sinumerik] "
                            "[--tool-table tool.tbl] [--csv out.csv] [--repeat N] [--override x] [--timing] "
                            "[--until t] program.nc\n");
            return 2;
        }
    }
    if (!program) {
        fprintf(stderr, "interp_run: no program\n");
        return 2;
    }
    interp_settings_of(&variables, &settings);
    settings.gcode.dialect = interp_dialect(dialect);
    if (settings.gcode.dialect < 0) {
        fprintf(stderr, "interp_run: --dialect %s: expected fanuc, linuxcnc or sinumerik\n", dialect);
        return 2;
    }
    if (table) {
        int status;
        text = read_all(table, &length);
        if (!text) {
            fprintf(stderr, "interp_run: cannot read %s\n", table);
            return 2;
        }
        status = tool_table_parse(text, length, table, &tools, &n_tools, error, sizeof error);
        free(text);
        if (status != 0) {
            fprintf(stderr, "interp_run: %s\n", error);
            return 1;
        }
        settings.gcode.tools = tools;
        settings.gcode.n_tools = n_tools;
    }
    text = read_all(program, &length);
    if (!text) {
        fprintf(stderr, "interp_run: cannot read %s\n", program);
        return 2;
    }
    if (interp_prepare(text, length, program, &settings, &prepared, error, sizeof error) != 0) {
        fprintf(stderr, "interp_run: %s\n", error);
        free(text);
        free(tools);
        return 1;
    }
    free(text);
    free(tools);
    t_prepared = now_ns();
    settings.gcode.tools = NULL;
    settings.gcode.n_tools = 0;
    heap = calloc(interp_heap_size(&prepared), sizeof *heap);
    if (!heap) return 3;
    interp_install(&prepared, heap, &layout);
    interp_release(&prepared);
    t_installed = now_ns();
    if (csv) {
        out = fopen(csv, "w");
        if (!out) {
            fprintf(stderr, "interp_run: cannot write %s\n", csv);
            return 2;
        }
        fprintf(out, "tick,t,x,y,z,feed,path_acceleration,u,line,move,s,x_program,y_program,z_program,vx,vy,vz\n");
    }
    if (repeat > 0) costs = malloc((size_t)repeat * sizeof *costs);
    for (k = 0; k < (repeat > 0 ? repeat : 1); k++) {
        double start;
        int64_t ticks;
        size_t i;
        for (i = 0; i < layout.n_nodes; i++) heap[layout.station + i] = (i == 0 || i + 1 == layout.n_nodes);
        interp_start(&state, &settings);
        if (interp_set_override(heap, &layout, &state, &settings, override) != 0) return 3;
        start = now_ns();
        if (k == 0) t_planned = start;
        while (!state.out.finished && !(until > 0.0 && (double)state.tick * settings.limits.period >= until)) {
            double before = timing ? now_ns() : 0.0;
            if (interp_tick(heap, &layout, &state, &settings) != 0) return 3;
            if (timing && now_ns() - before > longest) longest = now_ns() - before;
            if (out && k == 0)
                fprintf(out, "%lld,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%d,%zu,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g\n",
                        (long long)state.tick, (double)state.tick * settings.limits.period, state.out.x[0],
                        state.out.x[1], state.out.x[2], state.out.feed, state.out.acceleration, state.out.u,
                        state.out.line, state.move, state.s, state.out.program[0], state.out.program[1],
                        state.out.program[2], state.out.velocity[0], state.out.velocity[1], state.out.velocity[2]);
            if (state.hold) break;
        }
        ticks = state.tick;
        if (costs) costs[k] = (now_ns() - start) / (double)(ticks ? ticks : 1);
        if (k == 0)
            printf("moves %zu nodes %zu length %.9g m time %.6f s points %lld\n", layout.n_moves, layout.n_nodes,
                   layout.total, (double)ticks * settings.limits.period, (long long)ticks);
        if (k == 0 && timing)
            printf("timing parse_and_path %.3f s heap %.3f s first_plan %.3f s run %.3f s longest_tick %.4f s "
                   "peak %.1f MB\n",
                   (t_prepared - t_begin) * 1e-9, (t_installed - t_prepared) * 1e-9, (t_planned - t_installed) * 1e-9,
                   (now_ns() - t_planned) * 1e-9, longest * 1e-9, peak_mb());
    }
    if (out) fclose(out);
    if (costs) {
        qsort(costs, (size_t)repeat, sizeof *costs, compare);
        printf("ns_per_point median %.1f min %.1f max %.1f over %d runs\n", costs[repeat / 2], costs[0],
               costs[repeat - 1], repeat);
        free(costs);
    }
    free(heap);
    return 0;
}
