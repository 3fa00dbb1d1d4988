/* NURBS evaluation: knot span search, B-spline basis derivatives (Piegl & Tiller A2.3), rational point and
 * derivatives, Gauss-Legendre arc length, arc-length derivatives. Mirrored by
 * models/interpolator/nurbs.py operation for operation. */
#ifndef NURBS_H
#define NURBS_H

#include "model_constants.h" /* MAX_DEGREE, GL_NODES, GL_WEIGHTS: generated from models/interpolator/ */

#define NURBS_MAX_DERIVATIVE 3

/* A curve stored flat: knots (n + degree + 2 values for control points 0..n) and homogeneous control
 * points pw (4 per point: w x, w y, w z, w). */
typedef struct {
    int degree;
    int n; /* index of the last control point */
    const double *knots;
    const double *pw;
} NurbsView;

int nurbs_find_span(const double *knots, int p, double u, int lo, int hi);
void nurbs_basis_derivatives(const double *knots, int i, double u, int p, int nd,
                             double ders[NURBS_MAX_DERIVATIVE + 1][MAX_DEGREE + 1]);
/* out[k] = d^k C / du^k, k = 0..nd (nd <= 3); span searched in [lo, hi]. */
void nurbs_evaluate(const NurbsView *c, double u, int nd, int lo, int hi, double out[][3]);
/* First and last span of positive length inside [u0, u1]. */
void nurbs_span_range(const NurbsView *c, double u0, double u1, int *lo, int *hi);
double nurbs_gauss_length(const NurbsView *c, double ua, double ub, int lo, int hi);
/* Arc length from ua to ub (ua <= ub): Gauss-Legendre on each knot span's part (exact to rounding for short
 * steps, no quadrature across a knot). */
double nurbs_arc_length(const NurbsView *c, double ua, double ub, int lo, int hi);
/* From C, C', C'', C''': speed g, unit tangent t, d2C/ds2 k, d3C/ds3 kp. */
void nurbs_arc_length_derivatives(const double d[4][3], double *g, double t[3], double k[3], double kp[3]);

static inline double vec_dot(const double a[3], const double b[3]) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

#endif
