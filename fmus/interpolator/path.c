/* Path: nodes and velocity limits (see path.h); the same operations in the same order as
 * models/interpolator/path.py. */
#include "path.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "nurbs.h"

/* CHORD_SAFETY, TANGENT_TOLERANCE, COS_TURN, ... BIG: model_constants.h (through path.h) */
#ifndef COUPLING_SPEED_SHARE
#define COUPLING_SPEED_SHARE 0.75 /* models/interpolator/path.py (until model_constants.h generates it) */
#endif

static double min2(double a, double b) { return b < a ? b : a; }
static double max2(double a, double b) { return b > a ? b : a; }

void tangential_limits(const Limits *lim, const double t[3], int curved, double *at, double *jt) {
    double a = lim->acceleration, j = lim->jerk;
    double share_a = curved ? 0.5 : 1.0, share_j = curved ? (1.0 / 3.0) : 1.0;
    int i;
    for (i = 0; i < 3; i++) {
        double ti = fabs(t[i]);
        if (ti > 0.0) {
            a = min2(a, share_a * lim->axis_acceleration[i] / ti);
            j = min2(j, share_j * lim->axis_jerk[i] / ti);
        }
    }
    *at = a;
    *jt = j;
}

double curvature_limit(const Limits *lim, double kappa, const double k[3], const double kp[3], double at) {
    double v = BIG;
    int i;
    if (kappa > 0.0) {
        double rho = 1.0 / kappa, delta = CHORD_SAFETY * lim->chord;
        if (delta < rho)
            v = min2(v, 2.0 * sqrt(delta * (2.0 * rho - delta)) / lim->period);
        else
            v = min2(v, 2.0 * rho / lim->period);
        v = min2(v, sqrt(lim->centripetal / kappa));
        v = min2(v, cbrt(lim->jerk / (kappa * kappa)));
    }
    for (i = 0; i < 3; i++) {
        double ki = fabs(k[i]), kpi = fabs(kp[i]);
        if (ki > 0.0) {
            v = min2(v, sqrt(0.5 * lim->axis_acceleration[i] / ki));
            /* at = 0: the caller bounds the tangential acceleration instead (coupled_acceleration) */
            if (at > 0.0) v = min2(v, lim->axis_jerk[i] / (9.0 * at * ki));
        }
        if (kpi > 0.0) v = min2(v, cbrt(lim->axis_jerk[i] / (3.0 * kpi)));
    }
    return v;
}

double coupled_acceleration(const Limits *lim, const double t[3], double jt, const double k[3], const double kp[3],
                            double v, double at) {
    int i;
    for (i = 0; i < 3; i++) {
        double ki = fabs(k[i]);
        if (ki > 0.0 && v < BIG) {
            double budget = lim->axis_jerk[i] - fabs(t[i]) * jt - v * v * v * fabs(kp[i]);
            at = min2(at, budget / (3.0 * v * ki));
        }
    }
    return at;
}

double junction_limit(const Limits *lim, const double ta[3], const double ka[3], const double tb[3],
                      const double kb[3]) {
    double v = BIG, period = lim->period, dk[3], norm;
    int i;
    if (vec_dot(ta, tb) < 1.0 - TANGENT_TOLERANCE) {
        double dt[3];
        for (i = 0; i < 3; i++) dt[i] = tb[i] - ta[i];
        norm = sqrt(vec_dot(dt, dt));
        v = min2(min2(v, lim->acceleration * period / norm), lim->jerk * period * period / norm);
        for (i = 0; i < 3; i++) {
            double di = fabs(dt[i]);
            if (di > 0.0)
                v = min2(min2(v, 0.5 * lim->axis_acceleration[i] * period / di),
                         lim->axis_jerk[i] * period * period / (3.0 * di));
        }
    }
    for (i = 0; i < 3; i++) dk[i] = kb[i] - ka[i];
    norm = sqrt(vec_dot(dk, dk));
    if (norm > 0.0) {
        v = min2(v, sqrt(lim->jerk * period / norm));
        for (i = 0; i < 3; i++) {
            double di = fabs(dk[i]);
            if (di > 0.0) v = min2(v, sqrt(lim->axis_jerk[i] * period / (3.0 * di)));
        }
    }
    return v;
}

void arc_params(const GcMove *m, ArcParams *a) {
    memcpy(a->center, m->center, sizeof a->center);
    memcpy(a->end, m->end, sizeof a->end);
    memcpy(a->axes, m->axes, sizeof a->axes);
    a->theta0 = m->theta0, a->sweep = m->sweep, a->r0 = m->r0, a->r1 = m->r1, a->height = m->height;
}

double arc_length(const ArcParams *a) {
    double rm = 0.5 * (a->r0 + a->r1), planar = rm * a->sweep;
    return sqrt(planar * planar + a->height * a->height);
}

void arc_point(const ArcParams *a, double lam, double p[3]) {
    double theta, r;
    int ia = a->axes[0], ib = a->axes[1], in = a->axes[2];
    if (lam >= 1.0) {
        memcpy(p, a->end, 3 * sizeof *p);
        return;
    }
    theta = a->theta0 + lam * a->sweep;
    r = a->r0 + lam * (a->r1 - a->r0);
    p[ia] = a->center[ia] + r * cos(theta);
    p[ib] = a->center[ib] + r * sin(theta);
    p[in] = a->center[in] + lam * a->height;
}

void arc_tangent(const ArcParams *a, double lam, double t[3]) {
    double theta = a->theta0 + lam * a->sweep, r = a->r0 + lam * (a->r1 - a->r0), c = cos(theta), s = sin(theta);
    double d[3], norm;
    int i, ia = a->axes[0], ib = a->axes[1], in = a->axes[2];
    d[ia] = -r * s * a->sweep + (a->r1 - a->r0) * c;
    d[ib] = r * c * a->sweep + (a->r1 - a->r0) * s;
    d[in] = a->height;
    norm = sqrt(vec_dot(d, d));
    for (i = 0; i < 3; i++) t[i] = d[i] / norm;
}

/* geometry (tangent, curvature vector) at the arc's lam, for junctions */
static void arc_end_geometry(const ArcParams *a, double lam, double t[3], double k[3]) {
    double length = arc_length(a), omega = fabs(a->sweep) / length, theta = a->theta0 + lam * a->sweep;
    double w2 = omega * omega, r = a->r0 + lam * (a->r1 - a->r0);
    int ia = a->axes[0], ib = a->axes[1];
    arc_tangent(a, lam, t);
    k[0] = k[1] = k[2] = 0.0;
    k[ia] = -r * w2 * cos(theta);
    k[ib] = -r * w2 * sin(theta);
}

/* ---- growable sample arrays ---- */

typedef struct {
    double *s, *v, *at, *jt;
    size_t n, cap;
} Samples;

static int samples_push(Samples *x, double s, double v, double at, double jt) {
    if (x->n == x->cap) {
        size_t cap = x->cap ? 2 * x->cap : 2; /* a line or an arc: two samples (NURBS blocks grow) */
        double *a = realloc(x->s, cap * sizeof *a), *b, *c, *d;
        if (!a) return -1;
        x->s = a;
        b = realloc(x->v, cap * sizeof *b);
        if (!b) return -1;
        x->v = b;
        c = realloc(x->at, cap * sizeof *c);
        if (!c) return -1;
        x->at = c;
        d = realloc(x->jt, cap * sizeof *d);
        if (!d) return -1;
        x->jt = d;
        x->cap = cap;
    }
    x->s[x->n] = s, x->v[x->n] = v, x->at[x->n] = at, x->jt[x->n] = jt;
    x->n++;
    return 0;
}

static void samples_free(Samples *x) {
    free(x->s);
    free(x->v);
    free(x->at);
    free(x->jt);
    memset(x, 0, sizeof *x);
}

typedef struct {
    double t[3], kappa, v, at, jt, p[3];
} Info;

typedef struct {
    const NurbsView *curve;
    const Limits *lim;
    int lo, hi, line;
    const char *file, *text; /* the program's text, its line quoted in a refusal */
    size_t length;
    char *error;
    size_t error_size;
    Samples *out;
} Sampler;

/* The parser's format, quoting the block's line (gc_line_error). */
static void refuse(const Sampler *z, const char *expected) {
    gc_line_error(z->text, z->length, z->file, (size_t)z->line, expected, z->error, z->error_size);
}

static int point_info(Sampler *z, double u, Info *info) {
    double d[4][3], g, k[3], kp[3];
    nurbs_evaluate(z->curve, u, 3, z->lo, z->hi, d);
    nurbs_arc_length_derivatives((const double(*)[3])d, &g, info->t, k, kp);
    info->kappa = sqrt(vec_dot(k, k));
    if (!(g > 0.0) || !isfinite(g) || !isfinite(info->kappa) || !isfinite(vec_dot(kp, kp))) {
        char expected[160];
        snprintf(expected, sizeof expected,
                 "the NURBS block has a zero tangent or a singular point near u = %.9g (repeated control points?)", u);
        refuse(z, expected);
        return -1;
    }
    tangential_limits(z->lim, info->t, 1, &info->at, &info->jt);
    /* the speed gives way to the acceleration-curvature coupling down to half the other limits, then the
     * acceleration does (near a cusp) */
    info->v = max2(curvature_limit(z->lim, info->kappa, k, kp, info->at),
                   COUPLING_SPEED_SHARE * curvature_limit(z->lim, info->kappa, k, kp, 0.0));
    info->at = coupled_acceleration(z->lim, info->t, info->jt, k, kp, info->v, info->at);
    info->p[0] = d[0][0], info->p[1] = d[0][1], info->p[2] = d[0][2];
    return 0;
}

/* The speed limit of a sample (limit vb) ending an interval from a sample with limit va whose midpoint's limit is vm:
 * where vm is below both ends (a curvature peak between the samples) and the three differ by at most
 * CURVATURE_VARIATION of vm (a resolved peak, between samples that the sampling left unsplit), the vertex of the
 * parabola through them (it lies within the middle half; its dip below vm is at most 1/8 of the larger difference),
 * else vb. The samples' limits alone missed such peaks: 1 % more curvature between two samples, +0.68 % centripetal
 * acceleration on a random quintic. Unresolved variations (a near cusp's tip, where the turn between samples is
 * insignificant) keep their samples' limits: the midpoint there would slow a hairpin by 2 %. */
static double interior_limit(double va, double vm, double vb) {
    if (vm < va && vm < vb && va - vm <= CURVATURE_VARIATION * vm && vb - vm <= CURVATURE_VARIATION * vm) {
        double c = va + vb - 2.0 * vm;
        return vm - (vb - va) * (vb - va) / (8.0 * c);
    }
    return vb;
}

static int push(Sampler *z, double s, const Info *info, double v) {
    if (z->out->n >= MAX_SAMPLES) {
        char expected[80];
        snprintf(expected, sizeof expected, "the NURBS block needs more than %d samples", MAX_SAMPLES);
        refuse(z, expected);
        return -1;
    }
    if (samples_push(z->out, s, v, info->at, info->jt) != 0) {
        snprintf(z->error, z->error_size, "%s: out of memory for NURBS samples", z->file);
        return -1;
    }
    return 0;
}

static int refine(Sampler *z, double ua, const Info *ia, double ub, const Info *ib, double s_a, int depth,
                  double *s_b) {
    double um = 0.5 * (ua + ub), e[3], chord, kmax, kmin;
    Info im;
    int split;
    if (point_info(z, um, &im) != 0) return -1;
    e[0] = ib->p[0] - ia->p[0], e[1] = ib->p[1] - ia->p[1], e[2] = ib->p[2] - ia->p[2];
    chord = sqrt(vec_dot(e, e));
    kmax = max2(max2(ia->kappa, im.kappa), ib->kappa);
    kmin = min2(min2(ia->kappa, im.kappa), ib->kappa);
    split = vec_dot(ia->t, im.t) < COS_TURN || vec_dot(im.t, ib->t) < COS_TURN ||
            (kmax * chord > SIGNIFICANT_TURN && kmax - kmin > CURVATURE_VARIATION * kmax);
    if (split && depth < MAX_SAMPLE_DEPTH && um > ua && um < ub) {
        double s_m;
        if (refine(z, ua, ia, um, &im, s_a, depth + 1, &s_m) != 0) return -1;
        return refine(z, um, &im, ub, ib, s_m, depth + 1, s_b);
    }
    *s_b = s_a + nurbs_gauss_length(z->curve, ua, ub, z->lo, z->hi);
    return push(z, *s_b, ib, interior_limit(ia->v, im.v, ib->v));
}

static int knot_multiplicity(const NurbsView *c, double u) {
    int i, m = 0;
    for (i = 0; i <= c->n + c->degree + 1; i++) m += c->knots[i] == u;
    return m;
}

/* The junction limit at the knot u that ends the span `before` and starts `span`: the tangent and curvature vector
 * of the span before (left-sided derivatives) against those of the span after. */
static double knot_junction(const NurbsView *c, const Limits *lim, double u, int before, int span) {
    double d[4][3], g, ta[3], ka[3], tb[3], kb[3], kp[3];
    nurbs_evaluate(c, u, 3, before, before, d);
    nurbs_arc_length_derivatives((const double(*)[3])d, &g, ta, ka, kp);
    nurbs_evaluate(c, u, 3, span, span, d);
    nurbs_arc_length_derivatives((const double(*)[3])d, &g, tb, kb, kp);
    return junction_limit(lim, ta, ka, tb, kb);
}

static int nurbs_samples(Sampler *z, double u0, double u1, double end_t[2][3], double end_k[2][3]) {
    const double *kn = z->curve->knots;
    Info info0, ia, ib;
    double s = 0.0, d[4][3], g, kp[3];
    int span, j, multiplicity;
    if (point_info(z, u0, &info0) != 0 || push(z, 0.0, &info0, info0.v) != 0) return -1;
    for (span = z->lo; span <= z->hi; span++) {
        double a = max2(kn[span], u0), b = min2(kn[span + 1], u1), ua;
        if (!(b > a)) continue;
        multiplicity = knot_multiplicity(z->curve, a);
        if (a > u0 && multiplicity >= z->curve->degree - 1) {
            /* an inner knot of multiplicity m with p - m < 2: the curvature jumps there, a junction */
            double *v = &z->out->v[z->out->n - 1];
            *v = min2(*v, knot_junction(z->curve, z->lim, a, span - multiplicity, span));
        }
        ua = a;
        if (a == u0)
            ia = info0;
        else if (point_info(z, a, &ia) != 0)
            return -1;
        for (j = 1; j <= INITIAL_SUBDIVISION; j++) {
            double ub = j < INITIAL_SUBDIVISION ? a + (b - a) * (double)j / (double)INITIAL_SUBDIVISION : b;
            if (point_info(z, ub, &ib) != 0) return -1;
            if (refine(z, ua, &ia, ub, &ib, s, 0, &s) != 0) return -1;
            ua = ub;
            ia = ib;
        }
    }
    nurbs_evaluate(z->curve, u0, 3, z->lo, z->lo, d);
    nurbs_arc_length_derivatives((const double(*)[3])d, &g, end_t[0], end_k[0], kp);
    nurbs_evaluate(z->curve, u1, 3, z->hi, z->hi, d);
    nurbs_arc_length_derivatives((const double(*)[3])d, &g, end_t[1], end_k[1], kp);
    return 0;
}

void path_free(PathBuild *path) {
    size_t k;
    if (!path) return;
    free(path->move_s);
    free(path->move_length);
    free(path->move_cap);
    free(path->span_lo);
    free(path->span_hi);
    for (k = 0; k < path->n_curves && path->pw; k++) free(path->pw[k]);
    free(path->pw);
    free(path->node_s);
    free(path->node_vh);
    free(path->node_left);
    free(path->node_right);
    free(path->station);
    free(path->int_move);
    free(path->int_at);
    free(path->int_jt);
    free(path->int_cap);
    memset(path, 0, sizeof *path);
}

static void *array(size_t n, size_t size) { return calloc(n ? n : 1, size); }

/* The node and interval arrays, grown as the moves are sampled (a line, an arc or a dwell adds one node and one
 * interval; a NURBS block as many as its samples), trimmed to their length at the end. In a function returning int:
 * -1 when out of memory (the array left as it was). */
#define RESIZE(array, count)                                                                                       \
    do {                                                                                                           \
        void *resized_ = realloc((array), ((count) ? (count) : 1) * sizeof *(array));                              \
        if (!resized_) return -1;                                                                                  \
        (array) = resized_;                                                                                        \
    } while (0)

static int reserve_nodes(PathBuild *out, size_t nodes) {
    RESIZE(out->node_s, nodes);
    RESIZE(out->node_vh, nodes);
    RESIZE(out->node_left, nodes);
    RESIZE(out->node_right, nodes);
    RESIZE(out->station, nodes);
    return 0;
}

static int reserve_intervals(PathBuild *out, size_t ints) {
    RESIZE(out->int_move, ints);
    RESIZE(out->int_at, ints);
    RESIZE(out->int_jt, ints);
    RESIZE(out->int_cap, ints);
    return 0;
}

static int reserve_capped(double **capped, size_t n) {
    RESIZE(*capped, n);
    return 0;
}

static void add_node(PathBuild *out, double s, double vh, int left, int right, int station) {
    size_t k = out->n_nodes++;
    out->node_s[k] = s, out->node_vh[k] = vh, out->node_left[k] = left, out->node_right[k] = right;
    out->station[k] = (unsigned char)station;
}

/* One pass over the moves: each move's samples (scratch arrays reused from move to move), then at once its nodes and
 * intervals; the junction at a move's start needs only the move before's end tangent, curvature and last speed cap.
 * So no move keeps its samples: the path's memory is its nodes and intervals (about 90 bytes a line), not a sample
 * list per move. The same values in the same order as models/interpolator/path.py. */
int path_build(const GcProgram *program, const Limits *lim, const char *text, size_t text_length, const char *file,
               PathBuild *out, char *error, size_t error_size) {
    size_t n_moves = program->n_moves, index, c, node_cap, int_cap, capped_cap = 0;
    Samples x = {0};
    double *capped = NULL;          /* a NURBS block's speed caps over its neighbours */
    double end_t[2][3], end_k[2][3]; /* the move's tangent and curvature vector at its start and end */
    double prev_end_t[3] = {0, 0, 0}, prev_end_k[3] = {0, 0, 0}, prev_last_v = 0.0;
    double s = 0.0;
    int status = -1;
    memset(out, 0, sizeof *out);
    out->n_moves = n_moves;
    out->n_curves = program->n_curves;
    out->move_s = array(n_moves, sizeof(double));
    out->move_length = array(n_moves, sizeof(double));
    out->move_cap = array(n_moves, sizeof(double));
    out->span_lo = array(n_moves, sizeof(int));
    out->span_hi = array(n_moves, sizeof(int));
    out->pw = array(program->n_curves, sizeof(double *));
    node_cap = n_moves + 1, int_cap = n_moves; /* exact for a program of lines, arcs and dwells */
    if (!out->move_s || !out->move_length || !out->move_cap || !out->span_lo || !out->span_hi || !out->pw ||
        reserve_nodes(out, node_cap) || reserve_intervals(out, int_cap))
        goto oom;
    for (c = 0; c < program->n_curves; c++) {
        const GcCurve *cv = &program->curves[c];
        size_t k, n = (size_t)cv->n_points;
        double *pw = malloc(4 * n * sizeof *pw);
        if (!pw) goto oom;
        for (k = 0; k < n; k++) {
            double w = cv->weights[k];
            pw[4 * k] = w * cv->points[3 * k];
            pw[4 * k + 1] = w * cv->points[3 * k + 1];
            pw[4 * k + 2] = w * cv->points[3 * k + 2];
            pw[4 * k + 3] = w;
        }
        out->pw[c] = pw;
    }
    for (index = 0; index < n_moves; index++) {
        const GcMove *m = &program->moves[index];
        double length, base = s;
        size_t j, count;
        /* the program's contour tolerance (G64 P, CYCLE832) is the chord error allowed on its moves */
        Limits move_lim = *lim;
        if (m->tolerance > 0.0) move_lim.chord = m->tolerance;
        memset(end_k, 0, sizeof end_k);
        x.n = 0;
        out->move_s[index] = s;
        if (m->kind == MOVE_RAPID || m->kind == MOVE_LINE) {
            double t[3], at, jt;
            int i;
            for (i = 0; i < 3; i++) t[i] = m->end[i] - m->start[i];
            length = sqrt(vec_dot(t, t));
            for (i = 0; i < 3; i++) t[i] = t[i] / length;
            tangential_limits(lim, t, 0, &at, &jt);
            memcpy(end_t[0], t, sizeof t);
            memcpy(end_t[1], t, sizeof t);
            out->move_cap[index] = BIG;
            if (samples_push(&x, 0.0, BIG, at, jt) != 0 || samples_push(&x, length, BIG, at, jt) != 0) goto oom;
        } else if (m->kind == MOVE_DWELL) {
            /* no length: the path comes to rest on both of its nodes (stations), the schedule stands `dwell` there */
            length = 0.0;
            memset(end_t, 0, sizeof end_t);
            out->move_cap[index] = 0.0;
            if (samples_push(&x, 0.0, 0.0, lim->acceleration, lim->jerk) != 0 ||
                samples_push(&x, 0.0, 0.0, lim->acceleration, lim->jerk) != 0)
                goto oom;
        } else if (m->kind == MOVE_ARC) {
            ArcParams a;
            double rm, omega, rw, t[3] = {0, 0, 0}, k[3] = {0, 0, 0}, kp[3] = {0, 0, 0}, at, jt, kappa, v;
            int ia, ib, in;
            arc_params(m, &a);
            ia = a.axes[0], ib = a.axes[1], in = a.axes[2];
            length = arc_length(&a);
            rm = 0.5 * (a.r0 + a.r1);
            omega = fabs(a.sweep) / length;
            rw = rm * omega;
            t[ia] = t[ib] = min2(1.0, rw);
            k[ia] = k[ib] = rw * omega;
            kp[ia] = kp[ib] = rw * omega * omega;
            t[in] = fabs(a.height) / length;
            tangential_limits(lim, t, 1, &at, &jt);
            kappa = rm * omega * omega;
            v = curvature_limit(&move_lim, kappa, k, kp, at);
            arc_end_geometry(&a, 0.0, end_t[0], end_k[0]);
            arc_end_geometry(&a, 1.0, end_t[1], end_k[1]);
            out->move_cap[index] = v;
            if (samples_push(&x, 0.0, v, at, jt) != 0 || samples_push(&x, length, v, at, jt) != 0) goto oom;
        } else {
            const GcCurve *cv = &program->curves[m->curve];
            NurbsView view;
            Sampler z;
            int lo, hi;
            size_t n, i;
            view.degree = cv->degree;
            view.n = cv->n_points - 1;
            view.knots = cv->knots;
            view.pw = out->pw[m->curve];
            nurbs_span_range(&view, m->u0, m->u1, &lo, &hi);
            out->span_lo[index] = lo;
            out->span_hi[index] = hi;
            z.curve = &view, z.lim = &move_lim, z.lo = lo, z.hi = hi, z.line = m->line, z.file = file;
            z.text = text, z.length = text_length;
            z.error = error, z.error_size = error_size, z.out = &x;
            if (nurbs_samples(&z, m->u0, m->u1, end_t, end_k) != 0) goto fail;
            n = x.n;
            length = x.s[n - 1];
            if (n > capped_cap) {
                if (reserve_capped(&capped, n)) goto oom;
                capped_cap = n;
            }
            for (i = 0; i < n; i++) {
                /* the lowest of the neighbours and of every sample within one step (see models/interpolator/path.py) */
                double v = min2(min2(x.v[i > 0 ? i - 1 : 0], x.v[i]), x.v[i + 1 < n ? i + 1 : n - 1]);
                double window = min2(x.v[i], lim->max_feed) * lim->period;
                size_t jj;
                /* a step spans sample jj only at a speed above its distance / period */
                for (jj = i; jj >= 2 && x.s[i] - x.s[jj - 2] <= window; jj--)
                    v = min2(v, max2(x.v[jj - 2], (x.s[i] - x.s[jj - 2]) / lim->period));
                for (jj = i + 2; jj < n && x.s[jj] - x.s[i] <= window; jj++)
                    v = min2(v, max2(x.v[jj], (x.s[jj] - x.s[i]) / lim->period));
                capped[i] = v;
            }
            memcpy(x.v, capped, n * sizeof *capped);
            out->move_cap[index] = BIG;
        }
        out->move_length[index] = length;
        s += length;
        /* this move's nodes and intervals: a node where it starts (the junction with the move before), one per inner
         * sample, and the program's end; an interval between each two of its samples */
        count = x.n;
        if (out->n_nodes + count > node_cap) {
            node_cap = 2 * node_cap > out->n_nodes + count ? 2 * node_cap : out->n_nodes + count;
            if (reserve_nodes(out, node_cap)) goto oom;
        }
        if (out->n_ints + count > int_cap) {
            int_cap = 2 * int_cap > out->n_ints + count ? 2 * int_cap : out->n_ints + count;
            if (reserve_intervals(out, int_cap)) goto oom;
        }
        for (j = 0; j < count; j++) {
            if (j == 0) {
                if (index == 0) {
                    add_node(out, base, 0.0, -1, (int)index, 1);
                } else {
                    const double zero[3] = {0, 0, 0};
                    const GcMove *prev = &program->moves[index - 1];
                    int stop = prev->exact_stop || prev->kind == MOVE_DWELL || m->kind == MOVE_DWELL;
                    double v = 0.0; /* exact stop (G61, G9, before and after a dwell): at rest, a station */
                    if (!stop) {
                        const double *ka = (prev->kind == MOVE_RAPID || prev->kind == MOVE_LINE) ? zero : prev_end_k;
                        const double *kb = (m->kind == MOVE_RAPID || m->kind == MOVE_LINE) ? zero : end_k[0];
                        v = junction_limit(lim, prev_end_t, ka, end_t[0], kb);
                        v = min2(min2(v, prev_last_v), x.v[0]);
                    }
                    add_node(out, base, v, (int)index - 1, (int)index, stop);
                }
            } else if (j == count - 1) {
                if (index == n_moves - 1) add_node(out, base + x.s[j], 0.0, (int)index, -1, 1);
            } else {
                add_node(out, base + x.s[j], x.v[j], (int)index, (int)index, 0);
            }
            if (j < count - 1) {
                size_t i = out->n_ints++;
                out->int_move[i] = (int)index;
                out->int_at[i] = min2(x.at[j], x.at[j + 1]);
                out->int_jt[i] = min2(x.jt[j], x.jt[j + 1]);
                out->int_cap[i] = m->kind == MOVE_NURBS ? max2(x.v[j], x.v[j + 1]) : out->move_cap[index];
            }
        }
        memcpy(prev_end_t, end_t[1], sizeof prev_end_t);
        memcpy(prev_end_k, end_k[1], sizeof prev_end_k);
        prev_last_v = x.v[count - 1];
    }
    out->total = s;
    /* give back what a NURBS block's doubling reserved beyond the nodes and intervals */
    if (node_cap > out->n_nodes) reserve_nodes(out, out->n_nodes);
    if (int_cap > out->n_ints) reserve_intervals(out, out->n_ints);
    if (n_moves && out->node_s[out->n_nodes - 1] != out->total) out->node_s[out->n_nodes - 1] = out->total;
    status = 0;
    goto done;
oom:
    snprintf(error, error_size, "%s: out of memory while building the path", file);
fail:
    path_free(out);
done:
    samples_free(&x);
    free(capped);
    return status;
}
