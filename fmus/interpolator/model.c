/* Interpolator FMU: the part program (the `program` parameter, or resources/program.nc of the FMU) is read,
 * parsed and scheduled in exitInitializationMode; each doStep advances the interpolation periods that end
 * within the step (zero-order hold: the outputs are the last interpolation point at or before the end of
 * the step, exactly at it when the step is a multiple of the period). A change of the feed_override input
 * re-plans the rest of the program at the next moment of zero path acceleration. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "default_program.h"
#include "fmu_instance.h"

#define MAX_PROGRAM_BYTES (64u << 20)
#define PROGRAM_FILE_NAME "program.nc"

static void settings_of(const ModelVariables *v, InterpSettings *s) {
    const double *offsets[6][3] = {{&v->g54_x, &v->g54_y, &v->g54_z}, {&v->g55_x, &v->g55_y, &v->g55_z},
                                   {&v->g56_x, &v->g56_y, &v->g56_z}, {&v->g57_x, &v->g57_y, &v->g57_z},
                                   {&v->g58_x, &v->g58_y, &v->g58_z}, {&v->g59_x, &v->g59_y, &v->g59_z}};
    const double *centers[RBF_HIDDEN][RBF_INPUTS] = {
        {&v->rbf_center_1_1, &v->rbf_center_1_2, &v->rbf_center_1_3, &v->rbf_center_1_4},
        {&v->rbf_center_2_1, &v->rbf_center_2_2, &v->rbf_center_2_3, &v->rbf_center_2_4},
        {&v->rbf_center_3_1, &v->rbf_center_3_2, &v->rbf_center_3_3, &v->rbf_center_3_4},
        {&v->rbf_center_4_1, &v->rbf_center_4_2, &v->rbf_center_4_3, &v->rbf_center_4_4},
        {&v->rbf_center_5_1, &v->rbf_center_5_2, &v->rbf_center_5_3, &v->rbf_center_5_4}};
    int i, j;
    memset(s, 0, sizeof *s);
    s->limits.period = v->period;
    s->limits.acceleration = v->acceleration;
    s->limits.jerk = v->jerk;
    s->limits.centripetal = v->centripetal_acceleration;
    s->limits.chord = v->chord_error;
    s->limits.axis_acceleration[0] = v->axis_acceleration_x;
    s->limits.axis_acceleration[1] = v->axis_acceleration_y;
    s->limits.axis_acceleration[2] = v->axis_acceleration_z;
    s->limits.axis_jerk[0] = v->axis_jerk_x;
    s->limits.axis_jerk[1] = v->axis_jerk_y;
    s->limits.axis_jerk[2] = v->axis_jerk_z;
    s->max_feed = v->max_feed;
    s->rapid_feed = v->rapid_feed;
    s->limits.max_feed = v->max_feed > v->rapid_feed ? v->max_feed : v->rapid_feed;
    s->update.method = v->method;
    s->update.predictor = v->method == METHOD_CORRECTOR ? v->corrector_predictor : v->method;
    s->update.tolerance = v->corrector_tolerance;
    s->update.feedback = v->arc_length_feedback;
    s->update.rbf.width = v->rbf_width;
    s->update.rbf.offset[0] = v->rbf_offset_1, s->update.rbf.offset[1] = v->rbf_offset_2;
    s->update.rbf.offset[2] = v->rbf_offset_3, s->update.rbf.offset[3] = v->rbf_offset_4;
    s->update.rbf.scale[0] = v->rbf_scale_1, s->update.rbf.scale[1] = v->rbf_scale_2;
    s->update.rbf.scale[2] = v->rbf_scale_3, s->update.rbf.scale[3] = v->rbf_scale_4;
    for (j = 0; j < RBF_HIDDEN; j++)
        for (i = 0; i < RBF_INPUTS; i++) s->update.rbf.centers[j][i] = *centers[j][i];
    s->update.rbf.weights[0] = v->rbf_weight_1, s->update.rbf.weights[1] = v->rbf_weight_2;
    s->update.rbf.weights[2] = v->rbf_weight_3, s->update.rbf.weights[3] = v->rbf_weight_4;
    s->update.rbf.weights[4] = v->rbf_weight_5;
    s->update.rbf.bias = v->rbf_bias;
    s->gcode.start[0] = v->start_x, s->gcode.start[1] = v->start_y, s->gcode.start[2] = v->start_z;
    for (j = 0; j < 6; j++)
        for (i = 0; i < 3; i++) s->gcode.offsets[j][i] = *offsets[j][i];
}

static int hex_value(char c) {
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}

/* The resources folder as a file system path: FMI 3 passes a path, FMI 2 a file URI (percent-encoded).
 * -1: too long; -2: a %00 escape, which would cut the path short (another file would be read). */
static int resources_folder(const char *location, char *path, size_t size) {
    size_t n = 0;
    const char *s = location;
    if (strncmp(s, "file://", 7) == 0) {
        s += 7;
        if (strncmp(s, "localhost/", 10) == 0) s += 9;
    } else if (strncmp(s, "file:", 5) == 0) {
        s += 5;
    }
    while (*s && n + 1 < size) {
        if (s[0] == '%' && hex_value(s[1]) >= 0 && hex_value(s[2]) >= 0) {
            if (s[1] == '0' && s[2] == '0') return -2;
            path[n++] = (char)(hex_value(s[1]) * 16 + hex_value(s[2]));
            s += 3;
        } else {
            path[n++] = *s++;
        }
    }
    if (*s) return -1;
    while (n > 1 && path[n - 1] == '/') n--;
    path[n] = '\0';
    return 0;
}

/* Reads a whole file (at most MAX_PROGRAM_BYTES); NULL and a message on failure. */
static char *read_file(const char *path, size_t *length, char *message, size_t size) {
    FILE *f = fopen(path, "rb");
    char *text = NULL;
    size_t capacity = 0, n = 0;
    if (!f) {
        snprintf(message, size, "cannot open part program '%s': %s", path, strerror(errno));
        return NULL;
    }
    for (;;) {
        size_t got;
        if (n == capacity) {
            size_t c = capacity ? 2 * capacity : 65536;
            char *t;
            if (capacity >= MAX_PROGRAM_BYTES) {
                snprintf(message, size, "part program '%s' is larger than %u MB", path, MAX_PROGRAM_BYTES >> 20);
                free(text);
                fclose(f);
                return NULL;
            }
            t = realloc(text, c + 1);
            if (!t) {
                snprintf(message, size, "out of memory reading part program '%s'", path);
                free(text);
                fclose(f);
                return NULL;
            }
            text = t;
            capacity = c;
        }
        got = fread(text + n, 1, capacity - n, f);
        n += got;
        if (got == 0) break;
    }
    if (ferror(f)) {
        snprintf(message, size, "cannot read part program '%s': %s", path, strerror(errno));
        free(text);
        fclose(f);
        return NULL;
    }
    fclose(f);
    text[n] = '\0';
    *length = n;
    return text;
}

FmuStatus model_exit_initialization(FmuInstance *instance) {
    static const char *const function = "exitInitializationMode";
    ModelInternal *w = &instance->internal;
    const ModelVariables *v = &instance->v;
    char path[FMU_STRING_CAPACITY + 64], error[1024];
    const char *file, *text;
    char *owned = NULL;
    size_t length = 0;
    InterpPrepared prepared;
    int status;

    memset(w, 0, sizeof *w);
    settings_of(v, &w->settings);
    if (v->program[0] != '\0') {
        snprintf(path, sizeof path, "%s", v->program);
        file = v->program;
        owned = read_file(path, &length, error, sizeof error);
        if (!owned) {
            fmu_log(instance, FMU_ERROR, "logStatusError", "%s: parameter 'program': %s", function, error);
            return FMU_ERROR;
        }
        text = owned;
    } else if (instance->resource_path[0] != '\0') {
        char folder[FMU_STRING_CAPACITY];
        int bad = resources_folder(instance->resource_path, folder, sizeof folder);
        if (bad != 0) {
            fmu_log(instance, FMU_ERROR, "logStatusError", "%s: the resource location '%.200s' %s", function,
                    instance->resource_path, bad == -2 ? "holds a %00 escape" : "is too long");
            return FMU_ERROR;
        }
        snprintf(path, sizeof path, "%s/%s", folder, PROGRAM_FILE_NAME);
        file = "resources/" PROGRAM_FILE_NAME;
        owned = read_file(path, &length, error, sizeof error);
        if (!owned) {
            fmu_log(instance, FMU_ERROR, "logStatusError", "%s: parameter 'program' is empty and %s", function, error);
            return FMU_ERROR;
        }
        text = owned;
    } else {
        text = DEFAULT_PROGRAM;
        length = sizeof DEFAULT_PROGRAM - 1;
        file = "resources/" PROGRAM_FILE_NAME;
        fmu_log(instance, FMU_OK, "logEvents",
                "%s: no resource location was given: the built-in copy of resources/%s is used", function,
                PROGRAM_FILE_NAME);
    }
    status = interp_prepare(text, length, file, &w->settings, &prepared, error, sizeof error);
    free(owned);
    if (status != 0) {
        fmu_log(instance, FMU_ERROR, "logStatusError", "%s: part program %s", function, error);
        return FMU_ERROR;
    }
    if (fmu_allocate_heap(instance, function, interp_heap_size(&prepared)) != FMU_OK) {
        interp_release(&prepared);
        return FMU_ERROR;
    }
    interp_install(&prepared, instance->heap, &w->layout);
    interp_release(&prepared);
    interp_start(&w->state, &w->settings);
    if (interp_set_override(instance->heap, &w->layout, &w->state, &w->settings, v->feed_override) != 0) {
        fmu_log(instance, FMU_ERROR, "logStatusError", "%s: out of memory while scheduling the feed", function);
        return FMU_ERROR;
    }
    w->initialized = true;
    return FMU_OK;
}

FmuStatus model_do_step(FmuInstance *instance, double time, double step_size) {
    ModelInternal *w = &instance->internal;
    double target;
    int64_t until;
    if (!w->initialized ||
        interp_check(instance->heap, instance->heap_size, &w->layout, &w->state) != 0) {
        fmu_log(instance, FMU_ERROR, "logStatusError", "doStep: the interpolator's state is inconsistent (a corrupt "
                                                       "FMU state?)");
        return FMU_ERROR;
    }
    if (interp_set_override(instance->heap, &w->layout, &w->state, &w->settings, instance->v.feed_override) != 0) {
        fmu_log(instance, FMU_ERROR, "logStatusError", "doStep: out of memory while re-planning the feed");
        return FMU_ERROR;
    }
    target = floor((time + step_size - instance->start_time) / w->settings.limits.period + 1e-6);
    if (!(target < 9e15)) {
        fmu_log(instance, FMU_ERROR, "logStatusError", "doStep: t = %g s is too many interpolation periods",
                time + step_size);
        return FMU_ERROR;
    }
    until = (int64_t)target;
    while (w->state.tick < until) interp_tick(instance->heap, &w->layout, &w->state, &w->settings);
    return FMU_OK;
}

void model_update_outputs(FmuInstance *instance) {
    ModelVariables *v = &instance->v;
    InterpOutputs initial;
    const InterpOutputs *out;
    if (instance->internal.initialized) {
        out = &instance->internal.state.out;
    } else {
        InterpSettings s;
        settings_of(v, &s);
        interp_initial_outputs(&s, &initial);
        out = &initial;
    }
    v->x = out->x[0], v->y = out->x[1], v->z = out->x[2];
    v->x_program = out->program[0], v->y_program = out->program[1], v->z_program = out->program[2];
    v->feed_velocity_x = out->velocity[0], v->feed_velocity_y = out->velocity[1], v->feed_velocity_z = out->velocity[2];
    v->feed = out->feed;
    v->path_acceleration = out->acceleration;
    v->u = out->u;
    v->line_number = out->line;
    v->block_number = out->block;
    v->spindle_speed = out->spindle;
    v->spindle_on = out->spindle_on != 0;
    v->rapid = out->rapid != 0;
    v->finished = out->finished != 0;
}

void model_free_internal(FmuInstance *instance) { memset(&instance->internal, 0, sizeof instance->internal); }
