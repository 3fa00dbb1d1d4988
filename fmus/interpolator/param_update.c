/* NURBS parameter update (see param_update.h); the same operations in the same order as
 * models/interpolator/param_update.py. */
#include "param_update.h"

#include <math.h>
#include <string.h>

double rbf_output(const RbfParams *net, const double raw[RBF_INPUTS]) {
    double x[RBF_INPUTS], inv = 0.5 / (net->width * net->width), y = net->bias;
    int d, j;
    for (d = 0; d < RBF_INPUTS; d++) x[d] = (raw[d] - net->offset[d]) * net->scale[d];
    for (j = 0; j < RBF_HIDDEN; j++) {
        const double *c = net->centers[j];
        double e0 = x[0] - c[0], e1 = x[1] - c[1], e2 = x[2] - c[2], e3 = x[3] - c[3];
        y += net->weights[j] * exp(-(e0 * e0 + e1 * e1 + e2 * e2 + e3 * e3) * inv);
    }
    return y;
}

double predict_step(const NurbsState *st, double length, int predictor, const RbfParams *net, double ua, double ub) {
    double gg = vec_dot(st->d1, st->d1), g = sqrt(gg), up = 1.0 / g, upp = -vec_dot(st->d1, st->d2) / (gg * gg);
    double du, uppp, base, raw[RBF_INPUTS];
    if (predictor == METHOD_TAYLOR1) return length * up;
    du = length * up + 0.5 * upp * length * length;
    if (predictor == METHOD_TAYLOR2 || st->count < 3) return du;
    uppp = st->chord_prev > 0.0 ? (upp - st->upp_prev) / st->chord_prev : 0.0;
    base = du + uppp * length * length * length / 6.0;
    raw[0] = st->u - st->u2;
    raw[1] = st->u - st->u1;
    raw[2] = (st->u - ua) / (ub - ua);
    raw[3] = length;
    return base * (1.0 + rbf_output(net, raw));
}

double curvature_squared(const double d1[3], const double d2[3]) {
    double gg = vec_dot(d1, d1), x = vec_dot(d1, d2), k2 = (vec_dot(d2, d2) * gg - x * x) / (gg * gg * gg);
    return k2 > 0.0 ? k2 : 0.0;
}

double arc_of_chord(double chord, double k2a, double k2b) {
    return chord + 0.5 * (k2a + k2b) * chord * chord * chord / 24.0;
}

void nurbs_state_start(NurbsState *st, int move, const NurbsView *curve, double u0, int lo, int hi) {
    double d[3][3];
    nurbs_evaluate(curve, u0, 2, lo, hi, d);
    st->move = move;
    st->u = st->u1 = st->u2 = u0;
    st->count = 0;
    st->s_done = 0.0;
    st->s_actual = 0.0;
    memcpy(st->point, d[0], sizeof st->point);
    memcpy(st->d1, d[1], sizeof st->d1);
    memcpy(st->d2, d[2], sizeof st->d2);
    st->upp_prev = 0.0;
    st->chord_prev = 0.0;
}

void nurbs_state_accept(NurbsState *st, double u, const double d[3][3], double upp_prev, double chord, double arc) {
    st->u2 = st->u1;
    st->u1 = st->u;
    st->u = u;
    st->upp_prev = upp_prev;
    st->chord_prev = chord;
    memcpy(st->point, d[0], sizeof st->point);
    memcpy(st->d1, d[1], sizeof st->d1);
    memcpy(st->d2, d[2], sizeof st->d2);
    st->s_actual += arc;
    st->count++;
}

void nurbs_state_advance(NurbsState *st, const NurbsView *curve, double u0, double u1, int lo, int hi, double step,
                         const UpdateSettings *settings) {
    double u_end = u1, du, upp_now, u, p0[3], d[3][3], e[3], chord = 0.0, arc = 0.0;
    double gg = vec_dot(st->d1, st->d1);
    int k;
    du = predict_step(st, step, settings->predictor, &settings->rbf, u0, u1);
    upp_now = -vec_dot(st->d1, st->d2) / (gg * gg);
    u = st->u + du;
    if (!(u > st->u)) u = st->u + step / sqrt(vec_dot(st->d1, st->d1));
    if (!(u < u_end)) u = u_end;
    memcpy(p0, st->point, sizeof p0);
    if (settings->method != METHOD_CORRECTOR) {
        nurbs_evaluate(curve, u, 2, lo, hi, d);
        for (k = 0; k < 3; k++) e[k] = d[0][k] - p0[k];
        chord = sqrt(vec_dot(e, e));
        arc = arc_of_chord(chord, curvature_squared(st->d1, st->d2), curvature_squared(d[1], d[2]));
        nurbs_state_accept(st, u, (const double(*)[3])d, upp_now, chord, arc);
        return;
    }
    {
        /* Newton on the arc length of the step (Gauss-Legendre per knot span), bracketed */
        double lo_u = st->u, hi_u = u_end, u_eval = u;
        for (k = 0; k < MAX_NEWTON; k++) {
            double f, g, nxt;
            arc = nurbs_arc_length(curve, st->u, u, lo, hi);
            nurbs_evaluate(curve, u, 2, lo, hi, d);
            u_eval = u;
            f = arc - step;
            if (fabs(f) <= settings->tolerance * step) {
                /* converged: one more Newton step without a new arc length (its error is second order in f), so
                   the positions do not carry the tolerance's noise (1e-6 of a step would be 1e-10 m at 0.1 m/s,
                   up to 0.4 % of a 100 m/s^3 jerk in the third difference of the positions) */
                g = sqrt(vec_dot(d[1], d[1]));
                nxt = g > 0.0 ? u - f / g : u;
                if (nxt != u && nxt > st->u && nxt < u_end) {
                    arc = arc + g * (nxt - u);
                    nurbs_evaluate(curve, nxt, 2, lo, hi, d);
                    u_eval = nxt;
                }
                break;
            }
            if (f < 0.0) {
                if (u >= u_end) break;
                lo_u = u;
            } else {
                hi_u = u;
            }
            g = sqrt(vec_dot(d[1], d[1]));
            nxt = g > 0.0 ? u - f / g : -1.0;
            if (!(nxt > lo_u && nxt < hi_u)) nxt = 0.5 * (lo_u + hi_u);
            if (nxt == u) break;
            u = nxt;
        }
        e[0] = d[0][0] - p0[0], e[1] = d[0][1] - p0[1], e[2] = d[0][2] - p0[2];
        nurbs_state_accept(st, u_eval, (const double(*)[3])d, upp_now, sqrt(vec_dot(e, e)), arc);
    }
}
