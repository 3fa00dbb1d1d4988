/* ForceNet: the milling force of models/force_net.py from a neural network of the per-element cutting load.
 *
 * - model_instantiate (when the instance is created, and on reset): the weights file resources/weights.bin
 *   of the FMU is read from the resource location the importer passed (FMI 2: a file URI, FMI 3: a path) and
 *   checked (format, sizes, every layer's shape, checksum; see models/force_net.py): a missing, truncated or
 *   mismatched file fails the instantiation with the reason. Only when the importer passes no location at
 *   all is the built-in copy of the default file (default_weights.h) used. A retrained network is a new
 *   weights.bin in the FMU (models.force_net.install_weights): no recompilation.
 * - each doStep advances the spindle angle (generated), and the outputs are one evaluation of the tool at
 *   the angle reached (forcenet_tool: elements in contact, network, forces and moments). Material comes from
 *   the engagement map input where its cells are given (>= 0), else from the entry/exit window.
 * - the angle and the displacement history advance by the step clock (fmus/common/step_clock.h), so the same
 *   steps give the same outputs however the importer computed its communication points and step sizes. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "default_weights.h"
#include "cutting_state.h"
#include "fmu_instance.h"
#include "model_constants.h" /* OMEGA_MIN, TWO_PI: generated from models/cutting_force.py */
#include "resource_location.h"

/* the engagement input is the Workpiece's map (models/force_net.py: shape of "engagement") */
typedef char map_size_matches_the_model[(SIZE_engagement == MAP_ROWS * MAP_COLUMNS) ? 1 : -1];


FmuStatus model_instantiate(FmuInstance *instance, const char *function) {
    ModelInternal *in = &instance->internal;
    char path[4096], message[1024];
    const unsigned char *data;
    unsigned char *file = NULL;
    size_t size = 0;
    ForceNetLayout layout;
    const char *source = path;
    in->loaded = false;
    instance->cpu_features = forcenet_cpu_features(); /* once: a cpuid costs tens of us under a hypervisor */
    if (instance->resource_path[0] == '\0') {
        data = FORCENET_DEFAULT_WEIGHTS;
        size = sizeof FORCENET_DEFAULT_WEIGHTS;
        source = "the built-in copy of resources/" FORCENET_WEIGHTS_FILE;
        fmu_log(instance, FMU_OK, "logEvents", "%s: no resource location was given: %s is used", function, source);
    } else {
        if (fmu_resource_file(instance->resource_path, FORCENET_WEIGHTS_FILE, path, sizeof path, message,
                                   sizeof message) != 0) {
            fmu_log(instance, FMU_ERROR, "logStatusError", "%s: %s", function, message);
            return FMU_ERROR;
        }
        file = forcenet_read_file(path, &size, message, sizeof message);
        if (!file) {
            fmu_log(instance, FMU_ERROR, "logStatusError",
                    "%s: the force-net weights file cannot be read: %s (the FMU's resources/ must hold %s, "
                    "format in models/force_net.py)", function, message, FORCENET_WEIGHTS_FILE);
            return FMU_ERROR;
        }
        data = file;
    }
    if (forcenet_parse(data, size, &layout, NULL, message, sizeof message) != 0) {
        fmu_log(instance, FMU_ERROR, "logStatusError", "%s: force-net weights file '%s': %s", function, source,
                message);
        free(file);
        return FMU_ERROR;
    }
    if (fmu_allocate_heap(instance, function, layout.count) != FMU_OK) {
        free(file);
        return FMU_ERROR;
    }
    forcenet_parse(data, size, &in->net, instance->heap, message, sizeof message);
    free(file);
    in->loaded = true;
    fmu_log(instance, FMU_OK, "logEvents", "%s: network kernel %s", function,
            (instance->cpu_features & FORCENET_CPU_AVX2) ? "AVX2" : "baseline");
    return FMU_OK;
}

/* The model's time: the start time plus the clock's. */
static double clock_time(const FmuInstance *instance) {
    return instance->start_time + step_clock_seconds(&instance->internal.clock);
}

static double tooth_period(const ModelVariables *v) {
    return TWO_PI / ((double)v->n_flutes * fmax(v->spindle_speed, OMEGA_MIN));
}

FmuStatus model_exit_initialization(FmuInstance *instance) {
    ModelInternal *in = &instance->internal;
    in->warned_stopped = false;
    in->clock.ns = 0.0;
    in->clock.rest = 0.0;
    if (!in->loaded) {
        fmu_log(instance, FMU_ERROR, "logStatusError", "ExitInitializationMode: no force-net weights are loaded");
        return FMU_ERROR;
    }
    return history_start(instance, &in->history, in->net.count, instance->v.history_size, "ExitInitializationMode") == 0
               ? FMU_OK
               : FMU_ERROR;
}

FmuStatus model_do_step(FmuInstance *instance, double time, double step_size) {
    ModelVariables *v = &instance->v;
    ModelInternal *in = &instance->internal;
    StepClock clock = in->clock;
    const double start = clock_time(instance), h = step_clock_advance(&clock, time, step_size);
    FmuStatus status;
    if (history_record(instance, &in->history, v->history_size, start, h, v->displacement_x, v->displacement_y,
                       tooth_period(v), 1, v->spindle_speed >= OMEGA_MIN && v->axial_depth > 0.0, v->n_flutes,
                       v->spindle_speed) != 0)
        return FMU_ERROR;
    status = warn_feeding_a_stopped_spindle(instance, time, v->spindle_speed, OMEGA_MIN, v->feed_velocity_x,
                                            v->feed_velocity_y, v->axial_depth, v->entry_angle, v->exit_angle,
                                            &in->warned_stopped);
    model_update_states(v, h);
    in->clock = clock;
    return status;
}

void model_update_outputs(FmuInstance *instance) {
    ModelVariables *v = &instance->v;
    ForceNetCut cut;
    ForceNetTool tool;
    memset(&tool, 0, sizeof tool);
    /* (before the first step the history is empty: the delayed displacement is the current one) */
    history_delayed(instance, &instance->internal.history, 0, clock_time(instance), tooth_period(v),
                    v->displacement_x, v->displacement_y, &v->states.delayed_displacement_x,
                    &v->states.delayed_displacement_y);
    model_evaluate_equations(v);
    if (instance->internal.loaded) {
        cut.n_flutes = (int)v->n_flutes;
        cut.tool_diameter = v->tool_diameter;
        cut.helix_angle = v->helix_angle;
        cut.moment_height = v->moment_height;
        cut.runout_offset = v->runout_offset;
        cut.runout_angle = v->runout_angle;
        cut.displacement_x = v->displacement_x - v->states.delayed_displacement_x;
        cut.displacement_y = v->displacement_y - v->states.delayed_displacement_y;
        cut.spindle_speed = v->spindle_speed;
        cut.feed_velocity_x = v->feed_velocity_x;
        cut.feed_velocity_y = v->feed_velocity_y;
        cut.axial_depth = v->axial_depth;
        cut.entry_angle = v->entry_angle;
        cut.exit_angle = v->exit_angle;
        cut.angle = v->states.angle;
        cut.engagement = v->engagement;
        forcenet_tool(&instance->internal.net, instance->heap, &cut, &tool, instance->cpu_features);
    }
    v->Fx = tool.Fx;
    v->Fy = tool.Fy;
    v->Fz = tool.Fz;
    v->torque = tool.torque;
    v->power = tool.power;
    v->Mx = tool.Mx;
    v->My = tool.My;
    v->Mz = tool.Mz;
}

void model_free_internal(FmuInstance *instance) { (void)instance; }
