/* The step clock of the force models (CuttingForce, ForceNet): the time since the start of a run that their
 * spindle angle and displacement history advance by, the same however the importer does its time arithmetic.
 *
 * Importers hand doStep the same steps in different floating-point forms: a step h from t_n = n h, from t += h,
 * or the difference t_(n+1) - t_n of two communication points, which differs from h in its last bits. The angle
 * accumulates the steps, and at the edges of the engagement window (and, for the force net, at 2 pi) an edge
 * element goes in or out of contact on a 1-ulp change of it: single samples jumped by half the force.
 *
 * The clock counts whole nanoseconds and the rest of the steps apart: a step within 16 ulps of the importer's
 * time (at most 1 ps) of k whole nanoseconds is taken as the double nearest k ns (k / 1e9), so the same steps
 * give the same outputs in every form; any other step (below 1 ns, 1/3 ms, ...) is taken as given, the clock
 * keeping its part beyond whole nanoseconds, so its time does not drift from the sum of the steps.
 * models/step_clock.py has the same operations in the same order (the tests hold the two equal). Header only:
 * flat, part of a model's ModelInternal (copied into FMU states). */
#ifndef STEP_CLOCK_H
#define STEP_CLOCK_H

#include <float.h>
#include <math.h>

typedef struct {
    double ns;   /* whole nanoseconds since the start (an integer value) */
    double rest; /* s: what the steps had beyond whole nanoseconds, below half a nanosecond after each step */
} StepClock;

#define STEP_CLOCK_NS_PER_S 1e9
#define STEP_CLOCK_SNAP_ULPS 16.0   /* within this many ulps of the importer's time of whole ns: whole */
#define STEP_CLOCK_SNAP_LIMIT 1e-12 /* ... and never more than 1 ps off them */
#define STEP_CLOCK_MAX_NS 4503599627370496.0 /* 2^52 ns counted exactly (52 days); beyond, steps as given */

/* Advances the clock by a step of h from the importer's communication point `time`; returns the step the
 * model takes. */
static inline double step_clock_advance(StepClock *clock, double time, double h) {
    const double scaled = h * STEP_CLOCK_NS_PER_S;
    double whole = scaled < STEP_CLOCK_MAX_NS ? floor(scaled + 0.5) : 0.0, residual;
    if (whole >= 1.0 && whole + clock->ns < STEP_CLOCK_MAX_NS) {
        residual = h - whole / STEP_CLOCK_NS_PER_S;
        if (fabs(residual) <= fmin(STEP_CLOCK_SNAP_ULPS * DBL_EPSILON * (fabs(time) + h), STEP_CLOCK_SNAP_LIMIT))
            residual = 0.0;
        clock->ns += whole;
    } else {
        whole = 0.0;
        residual = h;
    }
    clock->rest += residual;
    if (fabs(clock->rest) < 1.0) {
        const double carry = floor(clock->rest * STEP_CLOCK_NS_PER_S + 0.5);
        if (carry != 0.0 && clock->ns + carry < STEP_CLOCK_MAX_NS) {
            clock->ns += carry;
            clock->rest -= carry / STEP_CLOCK_NS_PER_S;
        }
    }
    return residual == 0.0 ? whole / STEP_CLOCK_NS_PER_S : h;
}

/* The time since the start [s]. */
static inline double step_clock_seconds(const StepClock *clock) {
    return clock->ns / STEP_CLOCK_NS_PER_S + clock->rest;
}

#endif
