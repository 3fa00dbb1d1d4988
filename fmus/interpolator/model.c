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
#include "interp_settings.h"
#include "resource_location.h"
#include "tool_table.h"

#define MAX_PROGRAM_BYTES (64u << 20)
#define PROGRAM_FILE_NAME "program.nc"

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
    GcTool *tools = NULL;
    size_t n_tools = 0;
    int i, notes;

    memset(w, 0, sizeof *w);
    interp_settings_of(v, &w->settings);
    if (w->settings.gcode.dialect < 0) {
        fmu_log(instance, FMU_ERROR, "logStatusError", "%s: parameter 'dialect' is '%s': expected fanuc, linuxcnc or "
                "sinumerik", function, v->dialect);
        return FMU_ERROR;
    }
    if (v->tool_table[0] != '\0') {
        char *table_text = read_file(v->tool_table, &length, error, sizeof error);
        if (!table_text) {
            fmu_log(instance, FMU_ERROR, "logStatusError", "%s: parameter 'tool_table': %s", function, error);
            return FMU_ERROR;
        }
        status = tool_table_parse(table_text, length, v->tool_table, &tools, &n_tools, error, sizeof error);
        free(table_text);
        if (status != 0) {
            fmu_log(instance, FMU_ERROR, "logStatusError", "%s: parameter 'tool_table': %s", function, error);
            return FMU_ERROR;
        }
        w->settings.gcode.tools = tools;
        w->settings.gcode.n_tools = n_tools;
    }
    if (v->program[0] != '\0') {
        snprintf(path, sizeof path, "%s", v->program);
        file = v->program;
        owned = read_file(path, &length, error, sizeof error);
        if (!owned) {
            fmu_log(instance, FMU_ERROR, "logStatusError", "%s: parameter 'program': %s", function, error);
            free(tools);
            return FMU_ERROR;
        }
        text = owned;
    } else if (instance->resource_path[0] != '\0') {
        if (fmu_resource_file(instance->resource_path, PROGRAM_FILE_NAME, path, sizeof path, error,
                              sizeof error) != 0) {
            fmu_log(instance, FMU_ERROR, "logStatusError", "%s: parameter 'program' is empty and %s", function, error);
            free(tools);
            return FMU_ERROR;
        }
        file = "resources/" PROGRAM_FILE_NAME;
        owned = read_file(path, &length, error, sizeof error);
        if (!owned) {
            fmu_log(instance, FMU_ERROR, "logStatusError", "%s: parameter 'program' is empty and %s", function, error);
            free(tools);
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
    /* the parser has taken what it needs of the tool table: no pointer stays in the instance (FMU states) */
    free(tools);
    w->settings.gcode.tools = NULL;
    w->settings.gcode.n_tools = 0;
    if (status != 0) {
        fmu_log(instance, FMU_ERROR, "logStatusError", "%s: part program %s", function, error);
        return FMU_ERROR;
    }
    /* words the program may hold that the twin does not model (M0, M19, ...): each reported once */
    notes = prepared.program.n_notes;
    for (i = 0; i < notes; i++)
        fmu_log(instance, FMU_WARNING, "logStatusWarning", "%s: part program %s", function, prepared.program.notes[i]);
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
    return notes ? FMU_WARNING : FMU_OK;
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
    while (w->state.tick < until) {
        const bool still = w->state.hold && w->state.v == 0.0 && w->state.a == 0.0;
        InterpState before;
        if (still) memcpy(&before, &w->state, sizeof before);
        if (interp_tick(instance->heap, &w->layout, &w->state, &w->settings) != 0) {
            fmu_log(instance, FMU_ERROR, "logStatusError", "doStep: out of memory while planning the look-ahead "
                                                           "window (parameter 'lookahead_blocks')");
            return FMU_ERROR;
        }
        /* After the program's end every further tick changes only the tick count and the piece index, which
         * the last tick sets as every tick would; in a feed hold at standstill nothing but the tick count
         * changes. Skip to the last tick (a long step would otherwise spin through one tick per period: 112 s
         * for a 1e9 s step at 0.1 s). */
        if (w->state.tick + 1 < until &&
            (w->state.finished || (still && interp_holds_still(instance->heap, &w->layout, &before, &w->state))))
            w->state.tick = until - 1;
    }
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
        interp_settings_of(v, &s);
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
    v->tool_number = out->tool;
    v->tool_diameter = out->tool_diameter;
    v->tool_corner_radius = out->tool_corner_radius;
    v->tool_length = out->tool_length;
    v->tool_stick_out = out->tool_stick_out;
    v->tool_helix_angle = out->tool_helix;
    v->tool_flutes = out->tool_flutes;
    v->coolant = out->coolant;
}

void model_free_internal(FmuInstance *instance) { memset(&instance->internal, 0, sizeof instance->internal); }
