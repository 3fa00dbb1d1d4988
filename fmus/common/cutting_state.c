#include "cutting_state.h"

#include <math.h>

FmuStatus warn_feeding_a_stopped_spindle(FmuInstance *instance, double time, double spindle_speed, double omega_min,
                                         double feed_x, double feed_y, double axial_depth, double entry_angle,
                                         double exit_angle, bool *warned) {
    const double two_pi = 6.283185307179586;
    double feed, width;
    if (*warned || spindle_speed >= omega_min || axial_depth <= 0.0) return FMU_OK;
    feed = hypot(feed_x, feed_y);
    width = exit_angle - entry_angle;
    width -= two_pi * floor(width / two_pi);
    if (feed <= 0.0 || width <= 0.0) return FMU_OK;
    *warned = true;
    fmu_log(instance, FMU_WARNING, "logStatusWarning",
            "doStep: t = %g s: spindle_speed = %g rad/s is below %g rad/s (stopped) while the tool feeds at "
            "%g m/s into the cut (axial_depth = %g m): no chip, the forces are 0 (reported once)",
            time, spindle_speed, omega_min, feed, axial_depth);
    return FMU_WARNING;
}
