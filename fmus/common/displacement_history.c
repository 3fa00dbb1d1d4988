/* The displacement history of the force models' regenerative chip: displacement_history.h. */
#include "displacement_history.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmu_instance.h"

#define SAMPLE_SIZE 3       /* t, x, y */
#define INITIAL_SAMPLES 256 /* the ring's first size, in samples */

/* Sample k of the ring (k < count), 0 the oldest. A subtraction instead of a modulo: several of these per step and
 * delay, and a 64-bit division costs tens of cycles. */
static const double *sample(const FmuInstance *instance, const DisplacementHistory *h, size_t k) {
    size_t slot = h->next + h->capacity - h->count + k; /* < 2 capacity: next < capacity, k < count */
    if (slot >= h->capacity) slot -= h->capacity;
    return instance->heap + h->base + SAMPLE_SIZE * slot;
}

/* The heap resized to base + `capacity` samples, keeping its first base doubles and the ring's first `count`
 * samples (full and not yet wrapped, they are in order from slot 0). */
static int resize(FmuInstance *instance, DisplacementHistory *h, size_t capacity, size_t count, const char *function) {
    size_t keep = h->base + SAMPLE_SIZE * count;
    double *kept = keep ? malloc(keep * sizeof *kept) : NULL;
    if (keep && !kept) {
        fmu_log(instance, FMU_ERROR, "logStatusError", "%s: out of memory for the displacement history", function);
        return -1;
    }
    if (keep) memcpy(kept, instance->heap, keep * sizeof *kept);
    if (fmu_allocate_heap(instance, function, h->base + SAMPLE_SIZE * capacity) != FMU_OK) {
        free(kept);
        return -1;
    }
    if (keep) memcpy(instance->heap, kept, keep * sizeof *kept);
    free(kept);
    h->capacity = capacity;
    h->count = count;
    h->next = count % capacity;
    memset(h->hint, 0, sizeof h->hint);
    return 0;
}

int history_start(FmuInstance *instance, DisplacementHistory *h, size_t base, int32_t history_size,
                  const char *function) {
    size_t capacity = history_size > 0 ? (size_t)history_size : 1; /* >= 16: checked against its range */
    if (capacity > INITIAL_SAMPLES) capacity = INITIAL_SAMPLES;
    h->base = base;
    return resize(instance, h, capacity, 0, function);
}

int history_record(FmuInstance *instance, DisplacementHistory *h, int32_t history_size, double time, double step_size,
                   double x, double y, double period, int32_t periods, bool cutting, int32_t n_flutes,
                   double spindle_speed) {
    const size_t limit = (size_t)history_size;
    double *slot;
    if (h->count == h->capacity && h->capacity < limit &&
        resize(instance, h, 2 * h->capacity < limit ? 2 * h->capacity : limit, h->count, "DoStep") != 0)
        return -1;
    slot = instance->heap + h->base + SAMPLE_SIZE * h->next;
    slot[0] = time;
    slot[1] = x;
    slot[2] = y;
    h->next = (h->next + 1) % h->capacity;
    if (h->count < h->capacity) h->count++;
    if (h->count == limit && cutting) {
        /* the outputs after this step take its start as the newest sample: they need `periods` periods before it */
        const double oldest = sample(instance, h, 0)[0], span = periods * period;
        if (oldest > time - span) {
            char needed[96];
            if (periods == 1)
                snprintf(needed, sizeof needed, "one tooth period");
            else
                snprintf(needed, sizeof needed, "%d tooth periods (regeneration_passes) of", (int)periods);
            fmu_log(instance, FMU_ERROR, "logStatusError",
                    "doStep: t = %g s: the displacement history (history_size = %d samples, %g s at this step size) "
                    "is shorter than %s 2*pi/(n_flutes*spindle_speed) = %g s (n_flutes = %d, spindle_speed = %g "
                    "rad/s); set history_size to at least %.0f or use larger steps",
                    time, (int)history_size, time - oldest, needed, period, (int)n_flutes, spindle_speed,
                    ceil(span / step_size) + 2.0);
            return -1;
        }
    }
    return 0;
}

/* Whether sample lo is the last one at or before td (index n: the current inputs, after td). */
static bool brackets(const FmuInstance *instance, const DisplacementHistory *h, size_t lo, double td) {
    return lo < h->count && sample(instance, h, lo)[0] <= td &&
           (lo + 1 == h->count || sample(instance, h, lo + 1)[0] > td);
}

/* The sample found is remembered: one step later it is mostly the same or the one before (the ring dropped its
 * oldest sample), checked before a bisection; the sample times increase strictly, so the answer is the
 * bisection's. */
void history_delayed(const FmuInstance *instance, DisplacementHistory *h, int which, double time, double delay,
                     double x, double y, double *delayed_x, double *delayed_y) {
    size_t n = h->count, lo = 0, hi = n, hint = h->hint[which];
    /* the current inputs are the newest sample when they equal it (the outputs after a step: the inputs its start
     * recorded), else a sample at `time` (inputs set since): either way the current and the delayed displacement
     * are one period apart, as in the delay equation (at `time` - period the chip would regenerate over one step
     * less than a period, which moved the simulated onset of chatter by up to 7 % at 10 us steps) */
    const double *newest = n > 0 ? sample(instance, h, n - 1) : NULL;
    const double now = newest != NULL && newest[1] == x && newest[2] == y ? newest[0] : time;
    const double td = now - delay;
    const double current[SAMPLE_SIZE] = {now, x, y};
    const double *a = n > 0 ? sample(instance, h, 0) : current, *b;
    double w;
    if (td <= a[0]) {
        *delayed_x = a[1];
        *delayed_y = a[2];
        return;
    }
    if (brackets(instance, h, hint, td)) {
        lo = hint;
    } else if (hint > 0 && brackets(instance, h, hint - 1, td)) {
        lo = hint - 1;
    } else if (brackets(instance, h, hint + 1, td)) {
        lo = hint + 1;
    } else {
        /* t(lo) <= td < t(hi), where index n is the current inputs */
        while (hi - lo > 1) {
            size_t mid = lo + (hi - lo) / 2;
            if (sample(instance, h, mid)[0] <= td)
                lo = mid;
            else
                hi = mid;
        }
    }
    h->hint[which] = lo;
    a = sample(instance, h, lo);
    b = lo + 1 < n ? sample(instance, h, lo + 1) : current;
    w = (td - a[0]) / (b[0] - a[0]);
    *delayed_x = a[1] + w * (b[1] - a[1]);
    *delayed_y = a[2] + w * (b[2] - a[2]);
}
