/* Drives forcenet.c (the FMU's network and tool evaluation) without FMI, for the tests and the benchmark
 * (tests/test_forcenet*.py, tests/benchmarks/forcenet_speed.py compile it with the FMU's flags):
 *
 *   forcenet_run loads WEIGHTS             reads "n" then n lines of 7 features from stdin, prints n lines of
 *                                          3 loads [N/m] (%.17g)
 *   forcenet_run tool WEIGHTS N D HELIX ZP OMEGA VX VY AP ENTRY EXIT ANGLE
 *                                          prints Fx Fy Fz torque power Mx My Mz elements
 *   forcenet_run bench WEIGHTS N D HELIX OMEGA VX AP ENTRY EXIT EVALUATIONS
 *                                          times EVALUATIONS tool evaluations at angles spread over a
 *                                          revolution (each timed alone); prints the median, mean and
 *                                          minimum time per evaluation [ns] and the mean elements in contact
 */
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "forcenet.h"

static int load(const char *file, ForceNetLayout *layout, double **params) {
    char message[1024];
    size_t size = 0;
    unsigned char *data = forcenet_read_file(file, &size, message, sizeof message);
    if (!data || forcenet_parse(data, size, layout, NULL, message, sizeof message) != 0) {
        fprintf(stderr, "%s: %s\n", file, message);
        free(data);
        return -1;
    }
    *params = malloc(layout->count * sizeof **params);
    if (!*params) {
        free(data);
        return -1;
    }
    forcenet_parse(data, size, layout, *params, message, sizeof message);
    free(data);
    return 0;
}

static int compare(const void *a, const void *b) {
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static double now_ns(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec * 1e9 + (double)t.tv_nsec;
}

int main(int argc, char **argv) {
    ForceNetLayout layout;
    double *params = NULL;
    const unsigned cpu = forcenet_cpu_features(); /* once, as the FMU at instantiation */
    if (argc < 3 || load(argv[2], &layout, &params) != 0) {
        fprintf(stderr, "usage: %s loads|tool|bench WEIGHTS ... (see the source)\n", argv[0]);
        return 2;
    }
    if (strcmp(argv[1], "loads") == 0) {
        size_t n, i;
        double *features, *loads;
        if (scanf("%zu", &n) != 1) return 2;
        features = malloc((n + 1) * N_FEATURES * sizeof *features);
        loads = malloc((n + 1) * N_LOADS * sizeof *loads);
        if (!features || !loads) return 2;
        for (i = 0; i < n * N_FEATURES; i++)
            if (scanf("%lf", &features[i]) != 1) return 2;
        forcenet_network(&layout, params, features, n, loads, cpu);
        for (i = 0; i < n; i++) printf("%.17g %.17g %.17g\n", loads[3 * i], loads[3 * i + 1], loads[3 * i + 2]);
        free(features);
        free(loads);
    } else if (strcmp(argv[1], "tool") == 0 && argc == 14) {
        ForceNetCut cut;
        ForceNetTool out;
        memset(&cut, 0, sizeof cut); /* no runout, no vibration, no map */
        cut.n_flutes = atoi(argv[3]);
        cut.tool_diameter = atof(argv[4]);
        cut.helix_angle = atof(argv[5]);
        cut.moment_height = atof(argv[6]);
        cut.spindle_speed = atof(argv[7]);
        cut.feed_velocity_x = atof(argv[8]);
        cut.feed_velocity_y = atof(argv[9]);
        cut.axial_depth = atof(argv[10]);
        cut.entry_angle = atof(argv[11]);
        cut.exit_angle = atof(argv[12]);
        cut.angle = atof(argv[13]);
        forcenet_tool(&layout, params, &cut, &out, cpu);
        printf("%.17g %.17g %.17g %.17g %.17g %.17g %.17g %.17g %zu\n", out.Fx, out.Fy, out.Fz, out.torque,
               out.power, out.Mx, out.My, out.Mz, out.elements);
    } else if (strcmp(argv[1], "bench") == 0 && argc == 12) {
        ForceNetCut cut;
        ForceNetTool out;
        long count = atol(argv[11]), k;
        double *times, total = 0.0, elements = 0.0, sink = 0.0;
        if (count < 1) return 2;
        times = malloc((size_t)count * sizeof *times);
        if (!times) return 2;
        memset(&cut, 0, sizeof cut);
        cut.n_flutes = atoi(argv[3]);
        cut.tool_diameter = atof(argv[4]);
        cut.helix_angle = atof(argv[5]);
        cut.spindle_speed = atof(argv[6]);
        cut.feed_velocity_x = atof(argv[7]);
        cut.axial_depth = atof(argv[8]);
        cut.entry_angle = atof(argv[9]);
        cut.exit_angle = atof(argv[10]);
        for (k = 0; k < count; k++) {
            double start;
            cut.angle = 6.283185307179586 * (double)(k % 3600) / 3600.0;
            start = now_ns();
            forcenet_tool(&layout, params, &cut, &out, cpu);
            times[k] = now_ns() - start;
            total += times[k];
            elements += (double)out.elements;
            sink += out.Fx;
        }
        qsort(times, (size_t)count, sizeof *times, compare);
        printf("median_ns %.1f mean_ns %.1f min_ns %.1f elements %.2f checksum %.6g\n", times[count / 2],
               total / (double)count, times[0], elements / (double)count, sink);
        free(times);
    } else {
        fprintf(stderr, "usage: %s loads|tool|bench WEIGHTS ... (see the source)\n", argv[0]);
        free(params);
        return 2;
    }
    free(params);
    return 0;
}
