/* The engine's settings from the FMU's variables (see interp_settings.h). */
#include "interp_settings.h"

#include <string.h>

void interp_settings_of(const ModelVariables *v, InterpSettings *s) {
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
    s->lookahead = v->lookahead_blocks > 0 ? (size_t)v->lookahead_blocks : 0;
    s->gcode.start[0] = v->start_x, s->gcode.start[1] = v->start_y, s->gcode.start[2] = v->start_z;
    s->gcode.dialect = interp_dialect(v->dialect);
    s->gcode.home[0] = v->home_x, s->gcode.home[1] = v->home_y, s->gcode.home[2] = v->home_z;
    for (j = 0; j < 6; j++)
        for (i = 0; i < 3; i++) s->gcode.offsets[j][i] = *offsets[j][i];
}

int interp_dialect(const char *name) {
    if (strcmp(name, "fanuc") == 0) return DIALECT_FANUC;
    if (strcmp(name, "linuxcnc") == 0) return DIALECT_LINUXCNC;
    if (strcmp(name, "sinumerik") == 0) return DIALECT_SINUMERIK;
    return -1;
}

void interp_default_settings(InterpSettings *s) {
    ModelVariables v;
    model_set_start_values(&v);
    interp_settings_of(&v, s);
}
