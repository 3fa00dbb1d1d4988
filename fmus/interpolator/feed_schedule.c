/* Feedrate schedule (see feed_schedule.h); the same operations in the same order as
 * models/interpolator/schedule.py. */
#include "feed_schedule.h"

#include <math.h>
#include <stdlib.h>

#include "model_constants.h" /* BIG, BISECTIONS, VIOLATION_TOLERANCE: generated from models/interpolator/ */

static double min2(double a, double b) { return b < a ? b : a; }
static double max2(double a, double b) { return b > a ? b : a; }

double s_curve_time(double dv, double a, double j) {
    if (dv >= a * a / j) return dv / a + a / j;
    return 2.0 * sqrt(dv / j);
}

double s_curve_distance(double v0, double v1, double a, double j) {
    return 0.5 * (v0 + v1) * s_curve_time(fabs(v1 - v0), a, j);
}

double reach_up(double v0, double length, double a, double j) {
    double p, q, y, x;
    if (length <= 0.0) return v0;
    p = 2.0 * v0;
    q = length * sqrt(j);
    if (p == 0.0)
        y = cbrt(q);
    else
        y = 2.0 * sqrt(p / 3.0) * sinh(asinh(1.5 * q / p * sqrt(3.0 / p)) / 3.0);
    x = y * y;
    if (x >= a * a / j) {
        double qa = 0.5 / a, qb = v0 / a + 0.5 * a / j, qc = v0 * a / j - length;
        x = -2.0 * qc / (qb + sqrt(qb * qb - 4.0 * qa * qc));
    }
    return v0 + x;
}

/* What a bisection tests: can the velocity profile through v be done within the segment length? */
typedef struct {
    double va, vb, length, a, j;
} SCurveFit;

static int peak_fits(const SCurveFit *f, double v) {
    return s_curve_distance(f->va, v, f->a, f->j) + s_curve_distance(v, f->vb, f->a, f->j) <= f->length;
}

static int slowdown_fits(const SCurveFit *f, double v) { return s_curve_distance(v, f->vb, f->a, f->j) <= f->length; }

/* Narrows [good, bad] (fits at good, not at bad, one change between) by BISECTIONS halvings; the end that fits. */
static double bisect_fitting(int (*fits)(const SCurveFit *, double), const SCurveFit *f, double good, double bad) {
    int k;
    for (k = 0; k < BISECTIONS; k++) {
        double mid = 0.5 * (good + bad);
        if (fits(f, mid))
            good = mid;
        else
            bad = mid;
    }
    return good;
}

double lowest_feasible(double v_high, double v_low, double length, double a, double j) {
    SCurveFit f;
    f.va = v_high, f.vb = v_high, f.length = length, f.a = a, f.j = j;
    if (slowdown_fits(&f, v_low)) return v_low;
    return bisect_fitting(slowdown_fits, &f, v_high, v_low);
}

double segment_peak(double va, double vb, double length, double cap, double a, double j) {
    SCurveFit f;
    double top = max2(va, vb), floor_v = max2(cap, 0.0);
    f.va = va, f.vb = vb, f.length = length, f.a = a, f.j = j;
    if (cap >= top) return peak_fits(&f, cap) ? cap : bisect_fitting(peak_fits, &f, top, cap);
    return peak_fits(&f, floor_v) ? floor_v : bisect_fitting(peak_fits, &f, top, floor_v);
}

double s_curve_position(double v0, double v1, double a, double j, double w) {
    double dv = fabs(v1 - v0), t1, t2, total, delta, d1, t, dx;
    if (dv <= 0.0) return 0.0;
    if (dv >= a * a / j) {
        t1 = a / j;
        t2 = dv / a - a / j;
    } else {
        t1 = sqrt(dv / j);
        t2 = 0.0;
    }
    total = 2.0 * t1 + t2;
    delta = fabs(w - v0);
    d1 = 0.5 * j * t1 * t1;
    if (delta <= d1) {
        t = sqrt(2.0 * delta / j);
        dx = j * t * t * t / 6.0;
    } else if (delta <= d1 + j * t1 * t2) {
        double tau = (delta - d1) / (j * t1);
        t = t1 + tau;
        dx = j * t1 * t1 * t1 / 6.0 + d1 * tau + 0.5 * j * t1 * tau * tau;
    } else {
        double r = sqrt(2.0 * max2(dv - delta, 0.0) / j);
        t = total - r;
        dx = 0.5 * dv * total - (dv * r - j * r * r * r / 6.0);
    }
    return v1 >= v0 ? v0 * t + dx : v0 * t - dx;
}

typedef struct {
    double s0, length, va, vp, vb, a, j, cap, soft_cap;
    size_t first, last;
} Segment;

static double soft_of(const ScheduleView *v, double move) {
    return move < 0.0 ? BIG : v->soft[(size_t)move - v->move_base];
}

static double node_cap(const ScheduleView *v, size_t k) {
    return min2(min2(v->node_vh[k], soft_of(v, v->node_left[k])), soft_of(v, v->node_right[k]));
}

static size_t interval_at(const ScheduleView *v, double s) {
    size_t lo = 0, hi = v->n_nodes - 2;
    while (lo < hi) {
        size_t mid = (lo + hi + 1) / 2;
        if (v->node_s[mid] <= s)
            lo = mid;
        else
            hi = mid - 1;
    }
    return lo;
}

static size_t make_segments(const ScheduleView *v, double s_start, size_t first_interval, Segment *out) {
    size_t n = 0, i = first_interval, n_int = v->n_ints;
    double s0 = s_start;
    while (i < n_int) {
        double a = BIG, j = BIG, cap = 0.0, soft = BIG, end;
        size_t first = i;
        for (;;) {
            double m = v->int_move[i], sm;
            a = min2(a, v->int_at[i]);
            j = min2(j, v->int_jt[i]);
            sm = soft_of(v, m);
            soft = min2(soft, sm);
            cap = max2(cap, min2(sm, v->int_cap[i]));
            i++;
            if (i >= n_int || v->station[i] != 0.0 || v->node_vh[i] == 0.0) break; /* at rest there: a station */
        }
        end = v->node_s[i];
        out[n].s0 = s0, out[n].length = end - s0, out[n].va = out[n].vp = out[n].vb = 0.0;
        out[n].a = a, out[n].j = j, out[n].cap = cap, out[n].soft_cap = soft, out[n].first = first;
        out[n].last = i - 1;
        n++;
        s0 = end;
    }
    return n;
}

/* Returns 1 when the forward pass had to raise a station's velocity above its hard cap (node_vh; at rest at the
 * end): the start (v_start at s_start) cannot slow down in time for it within the S-curves between stations. */
static int velocities(const ScheduleView *view, Segment *segs, size_t n, double v_start, double *caps, double *b,
                      double *v) {
    size_t k;
    int raised = 0;
    for (k = 1; k < n; k++) caps[k] = node_cap(view, segs[k].first);
    caps[n] = 0.0;
    b[n] = 0.0;
    for (k = n - 1; k >= 1; k--) b[k] = min2(caps[k], reach_up(b[k + 1], segs[k].length, segs[k].a, segs[k].j));
    b[0] = BIG;
    v[0] = v_start;
    for (k = 1; k <= n; k++) {
        const Segment *sg = &segs[k - 1];
        double vk = min2(b[k], reach_up(v[k - 1], sg->length, sg->a, sg->j));
        /* (within the rounding of reach_up: the distance of a jerk-limited slow-down without reaching the
         * acceleration limit is not monotonic in its end velocity, so a stop the backward pass found to fit exactly,
         * rejected by an ulp, would be raised to the far side of that hump, e.g. a block ending at 12 mm/s instead
         * of at rest) */
        if (vk < v[k - 1] && s_curve_distance(vk, v[k - 1], sg->a, sg->j) > sg->length * (1.0 + VIOLATION_TOLERANCE))
            vk = lowest_feasible(v[k - 1], vk, sg->length, sg->a, sg->j);
        if (vk > (k < n ? view->node_vh[segs[k].first] : 0.0) * (1.0 + VIOLATION_TOLERANCE)) raised = 1;
        v[k] = vk;
    }
    for (k = 0; k < n; k++) {
        segs[k].va = v[k];
        segs[k].vb = v[k + 1];
        segs[k].vp = segment_peak(v[k], v[k + 1], segs[k].length, segs[k].cap, segs[k].a, segs[k].j);
    }
    return raised;
}

/* Marks the nodes that must become stations; returns how many. */
static size_t violations(ScheduleView *view, const Segment *segs, size_t n) {
    size_t added = 0, q;
    for (q = 0; q < n; q++) {
        const Segment *sg = &segs[q];
        int hard_only = sg->va > sg->soft_cap * (1.0 + VIOLATION_TOLERANCE) ||
                        sg->vb > sg->soft_cap * (1.0 + VIOLATION_TOLERANCE);
        double da = s_curve_distance(sg->va, sg->vp, sg->a, sg->j), db = s_curve_distance(sg->vp, sg->vb, sg->a, sg->j);
        double cruise = sg->length - da - db, worst_cap = BIG;
        size_t k, worst = 0;
        int found = 0;
        for (k = sg->first + 1; k <= sg->last; k++) {
            double allowed = hard_only ? view->node_vh[k] : node_cap(view, k);
            double w = allowed * (1.0 + VIOLATION_TOLERANCE), x = view->node_s[k] - sg->s0;
            int bad;
            if (x <= da) {
                if (sg->vp >= sg->va)
                    bad = w < sg->va || (w < sg->vp && x > s_curve_position(sg->va, sg->vp, sg->a, sg->j, w));
                else
                    bad = w < sg->vp || (w < sg->va && x < s_curve_position(sg->va, sg->vp, sg->a, sg->j, w));
            } else if (x <= da + cruise) {
                bad = w < sg->vp;
            } else {
                double y = x - da - cruise;
                if (sg->vb >= sg->vp)
                    bad = w < sg->vp || (w < sg->vb && y > s_curve_position(sg->vp, sg->vb, sg->a, sg->j, w));
                else
                    bad = w < sg->vb || (w < sg->vp && y < s_curve_position(sg->vp, sg->vb, sg->a, sg->j, w));
            }
            if (bad && allowed < worst_cap) {
                worst = k, worst_cap = allowed, found = 1;
            }
        }
        if (found) {
            view->station[worst] = 1.0;
            added++;
            continue;
        }
        if (sg->vp > sg->va && sg->vp > sg->vb && sg->last > sg->first) {
            double lo_s = sg->s0 + da, hi_s = sg->s0 + da + cruise;
            size_t i = sg->first;
            while (i < sg->last && view->node_s[i + 1] <= lo_s) i++;
            if (view->node_s[i + 1] >= hi_s || i == sg->last) {
                double m = view->int_move[i];
                double cap = hard_only ? view->int_cap[i] : min2(soft_of(view, m), view->int_cap[i]);
                if (sg->vp > cap * (1.0 + VIOLATION_TOLERANCE)) {
                    size_t node;
                    for (node = i; node <= i + 1; node++) {
                        if (view->station[node] == 0.0) {
                            view->station[node] = 1.0;
                            added++;
                        }
                    }
                }
            }
        }
    }
    return added;
}

static void put_piece(double *pc, double t, double s, double v, double a, double j) {
    pc[PC_T] = t, pc[PC_S] = s, pc[PC_V] = v, pc[PC_A] = a, pc[PC_J] = j;
}

static size_t s_curve_pieces(double *pieces, size_t n, double *t, double *s, double v0, double v1, double a,
                             double j) {
    double dv = v1 - v0, sign, t1, t2, jerk, am, v;
    if (dv == 0.0) return n;
    sign = dv > 0.0 ? 1.0 : -1.0;
    dv = fabs(dv);
    if (dv >= a * a / j) {
        t1 = a / j;
        t2 = dv / a - a / j;
    } else {
        t1 = sqrt(dv / j);
        t2 = 0.0;
    }
    jerk = sign * j;
    am = jerk * t1;
    v = v0;
    put_piece(pieces + PIECE_DOUBLES * n++, *t, *s, v, 0.0, jerk);
    *s += v * t1 + jerk * t1 * t1 * t1 / 6.0;
    v += 0.5 * jerk * t1 * t1;
    *t += t1;
    if (t2 > 0.0) {
        put_piece(pieces + PIECE_DOUBLES * n++, *t, *s, v, am, 0.0);
        *s += v * t2 + 0.5 * am * t2 * t2;
        v += am * t2;
        *t += t2;
    }
    put_piece(pieces + PIECE_DOUBLES * n++, *t, *s, v, am, -jerk);
    *s += v * t1 + 0.5 * am * t1 * t1 - jerk * t1 * t1 * t1 / 6.0;
    *t += t1;
    return n;
}

int schedule_plan(ScheduleView *view, double s_start, double v_start, double t_start, size_t first_piece,
                  size_t *n_pieces, int *hold, double *end_time) {
    Segment *segs;
    double *caps, *b, *v, t = t_start;
    size_t n, first, k, np = first_piece;
    *hold = 0;
    view->raised = 0;
    if (view->n_ints == 0) {
        put_piece(view->pieces + PIECE_DOUBLES * np++, t_start, s_start, 0.0, 0.0, 0.0);
        *n_pieces = np;
        *end_time = t_start;
        return 0;
    }
    segs = malloc((view->n_ints + 1) * sizeof *segs);
    caps = malloc(3 * (view->n_ints + 2) * sizeof *caps);
    if (!segs || !caps) {
        free(segs);
        free(caps);
        return -1;
    }
    b = caps + (view->n_ints + 2);
    v = b + (view->n_ints + 2);
    first = interval_at(view, s_start);
    for (;;) {
        n = make_segments(view, s_start, first, segs);
        view->raised = velocities(view, segs, n, v_start, caps, b, v);
        if (violations(view, segs, n) == 0) break;
    }
    for (k = 0; k < n; k++) {
        const Segment *sg = &segs[k];
        double s = sg->s0, da, db, cruise;
        if (sg->length <= 0.0) {
            double dwell = view->dwell[(size_t)view->int_move[sg->first] - view->move_base];
            if (dwell > 0.0) { /* a piece at rest (the only one with zero v, a and j before the end) */
                put_piece(view->pieces + PIECE_DOUBLES * np++, t, s, 0.0, 0.0, 0.0);
                t += dwell;
            }
            continue;
        }
        da = s_curve_distance(sg->va, sg->vp, sg->a, sg->j);
        db = s_curve_distance(sg->vp, sg->vb, sg->a, sg->j);
        cruise = max2(sg->length - da - db, 0.0);
        np = s_curve_pieces(view->pieces, np, &t, &s, sg->va, sg->vp, sg->a, sg->j);
        if (cruise > 0.0) {
            if (sg->vp <= 0.0) {
                put_piece(view->pieces + PIECE_DOUBLES * np++, t, s, 0.0, 0.0, 0.0);
                *hold = 1;
                *end_time = INFINITY;
                *n_pieces = np;
                free(segs);
                free(caps);
                return 0;
            }
            put_piece(view->pieces + PIECE_DOUBLES * np++, t, s, sg->vp, 0.0, 0.0);
            t += cruise / sg->vp;
            s += cruise;
        }
        np = s_curve_pieces(view->pieces, np, &t, &s, sg->vp, sg->vb, sg->a, sg->j);
    }
    put_piece(view->pieces + PIECE_DOUBLES * np++, t, view->total, 0.0, 0.0, 0.0);
    *end_time = t;
    *n_pieces = np;
    free(segs);
    free(caps);
    return 0;
}
