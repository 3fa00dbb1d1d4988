/* The compiled stepping loop of the orchestrator's fast path; see stepper.h and the semantics in
 * orchestrator/master.py. Every operation mirrors the Python loop there, in the same order, so
 * both paths produce bit-identical results: the same FMI calls with the same arguments, inputs
 * computed as source * factor (one IEEE multiplication, as in Python), times as
 * start + (double)k * base.
 */
#include "stepper.h"

#include <string.h>

#include "recorded_sample.h"

int stp_abi_version(void) {
    return STP_ABI_VERSION;
}

size_t stp_struct_size(int which) {
    switch (which) {
    case 0: return sizeof(stp_link);
    case 1: return sizeof(stp_column);
    case 2: return sizeof(stp_instance);
    case 3: return sizeof(stp_plan);
    case 4: return sizeof(stp_outcome);
    case 5: return sizeof(stp_recorded);
    case 6: return sizeof(stp_gate);
    case 7: return sizeof(stp_watch);
    default: return 0;
    }
}

static size_t bool_size(const stp_instance *s) {
    return s->fmi_version == 3 ? sizeof(fmi3Boolean) : sizeof(fmi2Boolean);
}

/* As Python reads a ctypes element: c_bool gives True/False (1/0), c_int the integer itself. */
static int read_bool(const void *p, int32_t kind) {
    return kind == STP_BOOL_FMI3 ? (*(const fmi3Boolean *)p ? 1 : 0) : *(const fmi2Boolean *)p;
}

static double read_value(const void *p, int32_t kind) {
    return kind == STP_REAL ? *(const double *)p : (double)read_bool(p, kind);
}

/* As Python stores into a ctypes element: c_bool(v) is v != 0, c_int(v) is v. */
static void write_bool(stp_instance *s, int64_t position, int value) {
    if (s->fmi_version == 3) {
        ((fmi3Boolean *)s->bool_in)[position] = value != 0;
    } else {
        ((fmi2Boolean *)s->bool_in)[position] = value;
    }
}

/* FineWhen.holds of orchestrator/scenario.py on the gate's output. */
static int gate_holds(const stp_gate *g) {
    if (g->sense == STP_IS) {
        return (read_bool(g->source, g->kind) != 0) == (g->threshold != 0.0);
    }
    if (g->kind != STP_REAL) {
        return 0; /* the scenario allows above/below on Real outputs only */
    }
    return g->sense == STP_ABOVE ? *(const double *)g->source > g->threshold
                                 : *(const double *)g->source < g->threshold;
}

/* The start of a coarse interval: fine if a gate holds now or held at one of the hold_intervals evaluations
 * before (_Intervals.evaluate of orchestrator/master.py). */
static void evaluate_gates(stp_plan *plan) {
    int64_t i;
    int now = 0;
    for (i = 0; i < plan->n_gates && !now; ++i) {
        now = gate_holds(&plan->gates[i]);
    }
    plan->fine = now || plan->hold_left > 0;
    plan->hold_left = now ? plan->hold_intervals : (plan->hold_left > 0 ? plan->hold_left - 1 : 0);
    if (plan->fine) {
        ++plan->fine_intervals;
    } else {
        ++plan->coarse_intervals;
    }
}

/* A watched output's value as master.py's _Triggers reads it: an Int32 as is, a Boolean as 0 or 1. */
static int32_t watch_value(const stp_watch *w) {
    const int32_t v = (int32_t)read_bool(w->source, w->kind);
    return w->boolean ? (v != 0) : v;
}

/* [[on_change]] at the start of tick k: 1 when a watch due at k fires (nothing is changed: Python checks the tick
 * itself); else 0, and every due watch remembers its value (a change to another value fires nothing). */
static int watches_fire(stp_plan *plan, int64_t k) {
    int64_t i;
    for (i = 0; i < plan->n_watches; ++i) {
        const stp_watch *w = &plan->watches[i];
        if (k % w->ticks_per_step == 0) {
            const int32_t v = watch_value(w);
            if (v != w->last && v == w->equals) {
                return 1;
            }
        }
    }
    for (i = 0; i < plan->n_watches; ++i) {
        stp_watch *w = &plan->watches[i];
        if (k % w->ticks_per_step == 0) {
            w->last = watch_value(w);
        }
    }
    return 0;
}

/* As RecordedData.at: a time beyond the recording's ends by more than its tolerance (or NaN) is an error. */
static int outside_recording(const stp_plan *plan, double t) {
    const double first = plan->recorded_time[0], last = plan->recorded_time[plan->recorded_samples - 1];
    return !(t >= first - plan->recorded_tolerance && t <= last + plan->recorded_tolerance);
}

/* Inputs of one step at time t: recorded samples, then links (master.py's _feed). Returns 1, with the
 * outcome filled in, when a recorded input is due outside the recording. */
static int feed(const stp_plan *plan, stp_instance *s, double t, stp_outcome *o) {
    int64_t i;
    if ((s->n_rec_real > 0 || s->n_rec_bool > 0) && outside_recording(plan, t)) {
        o->code = STP_OUT_OF_RECORDING;
        o->function = 0;
        o->time = t;
        return 1;
    }
    for (i = 0; i < s->n_rec_real; ++i) {
        stp_recorded *r = &s->rec_real[i];
        s->real_in[i] = recorded_sample(plan->recorded_time, r->values, 1, plan->recorded_samples, r->linear, t,
                                        &r->hint) * r->factor;
    }
    for (i = 0; i < s->n_rec_bool; ++i) {
        stp_recorded *r = &s->rec_bool[i];
        const double value = recorded_sample(plan->recorded_time, r->values, 1, plan->recorded_samples, r->linear,
                                             t, &r->hint);
        write_bool(s, i, r->linear ? value > r->factor : value != 0.0);
    }
    for (i = 0; i < s->n_real_links; ++i) {
        const stp_link *l = &s->real_links[i];
        s->real_in[l->position] = *(const double *)l->source * l->factor;
    }
    for (i = 0; i < s->n_bool_links; ++i) {
        const stp_link *l = &s->bool_links[i];
        write_bool(s, l->position, read_bool(l->source, l->source_kind));
    }
    return 0;
}

/* FMI status > Warning: fmpy raises FMICallException, so the Python path fails there too. */
static int failed(int status, stp_outcome *o, int function) {
    if (status > 1) {
        o->code = STP_FAILED;
        o->function = function;
        o->status = status;
        return 1;
    }
    return 0;
}

static int set_inputs(stp_instance *s, stp_outcome *o) {
    if (s->fmi_version == 3) {
        if (s->n_real_in > 0 &&
            failed((int)s->fmi3_set_float64(s->component, s->vr_real_in, (size_t)s->n_vr_real_in, s->real_in,
                                             (size_t)s->n_real_in), o, STP_FN_SET_REAL)) {
            return 1;
        }
        return s->n_bool_in > 0 &&
               failed((int)s->fmi3_set_boolean(s->component, s->vr_bool_in, (size_t)s->n_vr_bool_in,
                                               (const fmi3Boolean *)s->bool_in, (size_t)s->n_bool_in),
                      o, STP_FN_SET_BOOLEAN);
    }
    if (s->n_real_in > 0 &&
        failed((int)s->fmi2_set_real(s->component, s->vr_real_in, (size_t)s->n_real_in, s->real_in), o,
               STP_FN_SET_REAL)) {
        return 1;
    }
    return s->n_bool_in > 0 &&
           failed((int)s->fmi2_set_boolean(s->component, s->vr_bool_in, (size_t)s->n_bool_in,
                                           (const fmi2Boolean *)s->bool_in), o, STP_FN_SET_BOOLEAN);
}

/* Outputs in the order the Python path reads them: reals, booleans, Int32s. */
static int get_outputs(stp_instance *s, stp_outcome *o) {
    if (s->fmi_version == 3) {
        if (s->n_real_out > 0 &&
            failed((int)s->fmi3_get_float64(s->component, s->vr_real_out, (size_t)s->n_vr_real_out, s->real_out,
                                             (size_t)s->n_real_out), o, STP_FN_GET_REAL)) {
            return 1;
        }
        if (s->n_bool_out > 0 &&
            failed((int)s->fmi3_get_boolean(s->component, s->vr_bool_out, (size_t)s->n_vr_bool_out,
                                            (fmi3Boolean *)s->bool_out, (size_t)s->n_bool_out), o,
                   STP_FN_GET_BOOLEAN)) {
            return 1;
        }
        return s->n_int_out > 0 &&
               failed((int)s->fmi3_get_int32(s->component, s->vr_int_out, (size_t)s->n_vr_int_out, s->int_out,
                                             (size_t)s->n_int_out), o, STP_FN_GET_INTEGER);
    }
    if (s->n_real_out > 0 &&
        failed((int)s->fmi2_get_real(s->component, s->vr_real_out, (size_t)s->n_real_out, s->real_out), o,
               STP_FN_GET_REAL)) {
        return 1;
    }
    if (s->n_bool_out > 0 &&
        failed((int)s->fmi2_get_boolean(s->component, s->vr_bool_out, (size_t)s->n_bool_out,
                                        (fmi2Boolean *)s->bool_out), o, STP_FN_GET_BOOLEAN)) {
        return 1;
    }
    return s->n_int_out > 0 &&
           failed((int)s->fmi2_get_integer(s->component, s->vr_int_out, (size_t)s->n_int_out, s->int_out), o,
                  STP_FN_GET_INTEGER);
}

/* doStep; *terminate is set when an FMI 3 instance asks to end the simulation. */
static int do_step(stp_instance *s, double t, double h, int *terminate, stp_outcome *o) {
    if (s->fmi_version == 3) {
        fmi3Boolean event_needed = false, terminate_flag = false, early_return = false;
        fmi3Float64 last_successful = 0.0;
        if (failed((int)s->fmi3_do_step(s->component, t, h, true, &event_needed, &terminate_flag, &early_return,
                                        &last_successful), o, STP_FN_DO_STEP)) {
            return 1;
        }
        *terminate = terminate_flag ? 1 : 0;
        return 0;
    }
    *terminate = 0;
    return failed((int)s->fmi2_do_step(s->component, t, h, fmi2True), o, STP_FN_DO_STEP);
}

void stp_run(stp_plan *plan, int64_t first_tick, int64_t last_tick, double *rows, stp_outcome *o) {
    const int64_t n_instances = plan->n_instances, n_ticks = plan->n_ticks;
    const int64_t tpo = plan->ticks_per_output, width = 1 + plan->n_columns;
    int64_t k = first_tick, n_rows = 0, i;
    int stop = 0;

    o->code = STP_DONE;
    o->instance = -1;
    o->function = STP_FN_NONE;
    o->status = 0;
    o->time = 0.0;
    while (k < last_tick) {
        const double t = plan->start + (double)k * plan->base;
        if (plan->n_watches > 0 && watches_fire(plan, k)) {
            o->code = STP_EVENT;
            o->time = t;
            break;
        }
        for (i = 0; i < n_instances; ++i) {
            stp_instance *s = &plan->instances[i];
            if (s->snapshot) {
                memcpy(s->real_prev, s->real_out, (size_t)s->n_real_out * sizeof(double));
                memcpy(s->bool_prev, s->bool_out, (size_t)s->n_bool_out * bool_size(s));
            }
        }
        for (i = 0; i < n_instances; ++i) {
            stp_instance *s = &plan->instances[i];
            int64_t m, next;
            int terminate = 0, stepped;
            if (plan->n_gates > 0 && i == plan->first_variable && k % plan->ticks_per_interval == 0) {
                evaluate_gates(plan);
            }
            m = s->variable && !plan->fine ? plan->ticks_per_interval : s->ticks_per_step;
            if (k % m != 0) {
                continue;
            }
            next = k + m < n_ticks ? k + m : n_ticks;
            stepped = !(feed(plan, s, t, o) || set_inputs(s, o) ||
                        do_step(s, t, (plan->start + (double)next * plan->base) - t, &terminate, o));
            if (stepped && s->variable) {
                ++plan->variable_steps;
            }
            if (!stepped || (s->get_after_step && get_outputs(s, o))) {
                o->instance = (int32_t)i;
                o->time = t;
                o->tick = k;
                o->rows = n_rows;
                return;
            }
            if (terminate) {
                o->code = STP_TERMINATED;
                o->instance = (int32_t)i;
                o->time = t;
            }
        }
        ++k;
        if (k % tpo == 0) {
            const double t_row = plan->start + (double)k * plan->base;
            double *row = rows + n_rows * width;
            for (i = 0; i < n_instances; ++i) {
                stp_instance *s = &plan->instances[i];
                if (s->get_at_rows && get_outputs(s, o)) {
                    o->instance = (int32_t)i;
                    o->time = t_row;
                    o->tick = k;
                    o->rows = n_rows;
                    return;
                }
            }
            row[0] = t_row;
            for (i = 0; i < plan->n_columns; ++i) {
                row[1 + i] = read_value(plan->columns[i].source, plan->columns[i].kind);
            }
            ++n_rows;
            if (plan->should_stop != NULL && plan->should_stop(t_row)) {
                stop = 1;
            }
        }
        if (stop || o->code == STP_TERMINATED) {
            break;
        }
    }
    if (stop && o->code == STP_DONE) {
        o->code = STP_STOPPED;
    }
    o->tick = k;
    o->rows = n_rows;
}
