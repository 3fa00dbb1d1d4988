/* The displacement history behind the regenerative chip thickness, shared by the force models (CuttingForce,
 * ForceNet), which take the same displacement inputs:
 *
 * - each doStep records (t, displacement_x, displacement_y), the inputs at the start of the step, in a ring of
 *   `history_size` samples in the instance heap (so FMU states carry it), after the heap's first `base`
 *   doubles (kept: ForceNet's network). The ring starts small and doubles as samples arrive until it holds
 *   history_size of them: a short run (and its FMU states) stays small, and the values do not depend on the
 *   growth;
 * - the displacement one tooth period T (or k periods: multiple regeneration) before the current inputs is
 *   interpolated linearly over those samples and the current inputs. The current inputs are the newest sample when they equal it (after a doStep: the inputs
 *   its start recorded, held over the step), else a sample at the instance time (inputs set since), so the
 *   current and the delayed displacement are always one period apart. Before the oldest sample the oldest value
 *   is used (no history yet: no regeneration).
 *
 * models.cutting_force.DisplacementHistory is the same algorithm in Python. */
#ifndef DISPLACEMENT_HISTORY_H
#define DISPLACEMENT_HISTORY_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

struct FmuInstance;

#define HISTORY_DELAYS 3 /* delays looked up per output (multiple regeneration: 1 .. 3 tooth periods) */

/* The ring's bookkeeping: flat, part of a model's ModelInternal (copied into FMU states). */
typedef struct {
    size_t base;                 /* heap doubles before the ring */
    size_t capacity;             /* samples the ring holds now (grows to history_size) */
    size_t count;                /* samples stored, <= capacity */
    size_t next;                 /* slot the next sample goes to */
    size_t hint[HISTORY_DELAYS]; /* per delay, the sample its last lookup started from (a search hint) */
} DisplacementHistory;

/* At the end of initialization: an empty ring after the heap's first `base` doubles (kept). 0, or -1 (logged). */
int history_start(struct FmuInstance *instance, DisplacementHistory *history, size_t base, int32_t history_size,
                  const char *function);

/* In doStep at `time`: records the sample, growing the ring up to history_size; then, when the ring is full,
 * `cutting` and its oldest sample newer than `periods` tooth periods `period` before the step's start (what the
 * outputs after the step need), fails naming history_size, n_flutes and spindle_speed and the size needed. 0, or
 * -1 (logged). */
int history_record(struct FmuInstance *instance, DisplacementHistory *history, int32_t history_size, double time,
                   double step_size, double x, double y, double period, int32_t periods, bool cutting,
                   int32_t n_flutes, double spindle_speed);

/* The displacement `delay` (0 .. HISTORY_DELAYS - 1: its search hint) before the current inputs (x, y): before the
 * newest sample's time when they equal it, else before `time` (remembers where it found it: history->hint). */
void history_delayed(const struct FmuInstance *instance, DisplacementHistory *history, int which, double time,
                     double delay, double x, double y, double *delayed_x, double *delayed_y);

#endif
