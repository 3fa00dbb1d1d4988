/* Checks on the cutting state (spindle speed, feed, axial depth, engagement window) shared by the
 * force models (CuttingForce, ForceNet), which take the same inputs. */
#ifndef CUTTING_STATE_H
#define CUTTING_STATE_H

#include <stdbool.h>
#include "fmu_instance.h"

/* A stopped spindle (below omega_min) fed into an engaged cut would break the tool; the force models
 * cut nothing instead and say so once (*warned). Returns FMU_WARNING when it warns, else FMU_OK. */
FmuStatus warn_feeding_a_stopped_spindle(FmuInstance *instance, double time, double spindle_speed, double omega_min,
                                         double feed_x, double feed_y, double axial_depth, double entry_angle,
                                         double exit_angle, bool *warned);

#endif
