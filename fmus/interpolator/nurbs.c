/* NURBS evaluation (see nurbs.h); the same operations in the same order as models/interpolator/nurbs.py. */
#include "nurbs.h"

#include <math.h>

static const double BINOMIAL[4][4] = {{1.0, 0, 0, 0}, {1.0, 1.0, 0, 0}, {1.0, 2.0, 1.0, 0}, {1.0, 3.0, 3.0, 1.0}};

int nurbs_find_span(const double *knots, int p, double u, int lo, int hi) {
    int low, high, mid;
    (void)p;
    if (u >= knots[hi + 1]) return hi;
    if (u <= knots[lo]) return lo;
    low = lo;
    high = hi + 1;
    mid = (low + high) / 2;
    while (u < knots[mid] || u >= knots[mid + 1]) {
        if (u < knots[mid])
            high = mid;
        else
            low = mid;
        mid = (low + high) / 2;
    }
    return mid;
}

void nurbs_basis_derivatives(const double *knots, int i, double u, int p, int nd,
                             double ders[NURBS_MAX_DERIVATIVE + 1][MAX_DEGREE + 1]) {
    double ndu[MAX_DEGREE + 1][MAX_DEGREE + 1];
    double left[MAX_DEGREE + 1], right[MAX_DEGREE + 1];
    double a[2][MAX_DEGREE + 1];
    double factor;
    int j, r, k;
    ndu[0][0] = 1.0;
    for (j = 1; j <= p; j++) {
        double saved = 0.0;
        left[j] = u - knots[i + 1 - j];
        right[j] = knots[i + j] - u;
        for (r = 0; r < j; r++) {
            double temp;
            ndu[j][r] = right[r + 1] + left[j - r];
            temp = ndu[r][j - 1] / ndu[j][r];
            ndu[r][j] = saved + right[r + 1] * temp;
            saved = left[j - r] * temp;
        }
        ndu[j][j] = saved;
    }
    for (j = 0; j <= p; j++) ders[0][j] = ndu[j][p];
    for (r = 0; r <= p; r++) {
        int s1 = 0, s2 = 1;
        a[0][0] = 1.0;
        for (k = 1; k <= nd; k++) {
            double d = 0.0;
            int rk = r - k, pk = p - k, j1, j2, t;
            if (r >= k) {
                a[s2][0] = a[s1][0] / ndu[pk + 1][rk];
                d = a[s2][0] * ndu[rk][pk];
            }
            j1 = rk >= -1 ? 1 : -rk;
            j2 = (r - 1 <= pk) ? k - 1 : p - r;
            for (j = j1; j <= j2; j++) {
                a[s2][j] = (a[s1][j] - a[s1][j - 1]) / ndu[pk + 1][rk + j];
                d += a[s2][j] * ndu[rk + j][pk];
            }
            if (r <= pk) {
                a[s2][k] = -a[s1][k - 1] / ndu[pk + 1][r];
                d += a[s2][k] * ndu[r][pk];
            }
            ders[k][r] = d;
            t = s1, s1 = s2, s2 = t;
        }
    }
    factor = (double)p;
    for (k = 1; k <= nd; k++) {
        for (j = 0; j <= p; j++) ders[k][j] *= factor;
        factor *= (double)(p - k);
    }
}

void nurbs_evaluate(const NurbsView *c, double u, int nd, int lo, int hi, double out[][3]) {
    double ders[NURBS_MAX_DERIVATIVE + 1][MAX_DEGREE + 1];
    double aw[NURBS_MAX_DERIVATIVE + 1][4];
    int p = c->degree, i = nurbs_find_span(c->knots, p, u, lo, hi), k, j, m;
    double w0;
    nurbs_basis_derivatives(c->knots, i, u, p, nd, ders);
    for (k = 0; k <= nd; k++) {
        double x = 0.0, y = 0.0, z = 0.0, w = 0.0;
        for (j = 0; j <= p; j++) {
            const double *q = c->pw + 4 * (i - p + j);
            double b = ders[k][j];
            x += b * q[0];
            y += b * q[1];
            z += b * q[2];
            w += b * q[3];
        }
        aw[k][0] = x, aw[k][1] = y, aw[k][2] = z, aw[k][3] = w;
    }
    w0 = aw[0][3];
    for (k = 0; k <= nd; k++) {
        double vx = aw[k][0], vy = aw[k][1], vz = aw[k][2];
        for (m = 1; m <= k; m++) {
            double f = BINOMIAL[k][m] * aw[m][3];
            const double *prev = out[k - m];
            vx -= f * prev[0];
            vy -= f * prev[1];
            vz -= f * prev[2];
        }
        out[k][0] = vx / w0;
        out[k][1] = vy / w0;
        out[k][2] = vz / w0;
    }
}

void nurbs_span_range(const NurbsView *c, double u0, double u1, int *lo, int *hi) {
    int l = c->degree, h = c->n;
    while (c->knots[l + 1] <= u0) l++;
    while (c->knots[h] >= u1) h--;
    *lo = l;
    *hi = h;
}

double nurbs_gauss_length(const NurbsView *c, double ua, double ub, int lo, int hi) {
    double half = 0.5 * (ub - ua), mid = 0.5 * (ua + ub), total = 0.0, d[2][3];
    int k;
    for (k = 0; k < 5; k++) {
        nurbs_evaluate(c, mid + half * GL_NODES[k], 1, lo, hi, d);
        total += GL_WEIGHTS[k] * sqrt(vec_dot(d[1], d[1]));
    }
    return total * half;
}

void nurbs_arc_length_derivatives(const double d[4][3], double *g, double t[3], double k[3], double kp[3]) {
    const double *d1 = d[1], *d2 = d[2], *d3 = d[3];
    double gg = vec_dot(d1, d1), up, d12, upp, uppp, up2, up3;
    int a;
    *g = sqrt(gg);
    up = 1.0 / *g;
    d12 = vec_dot(d1, d2);
    upp = -d12 / (gg * gg);
    uppp = -(vec_dot(d2, d2) + vec_dot(d1, d3)) / (gg * gg * *g) + 4.0 * d12 * d12 / (gg * gg * gg * *g);
    up2 = up * up;
    up3 = up2 * up;
    for (a = 0; a < 3; a++) {
        t[a] = d1[a] * up;
        k[a] = d2[a] * up2 + d1[a] * upp;
        kp[a] = d3[a] * up3 + 3.0 * d2[a] * up * upp + d1[a] * uppp;
    }
}

double nurbs_arc_length(const NurbsView *c, double ua, double ub, int lo, int hi) {
    double a = ua, total = 0.0;
    int span = nurbs_find_span(c->knots, c->degree, ua, lo, hi);
    while (a < ub && span <= hi) {
        double b = c->knots[span + 1] < ub ? c->knots[span + 1] : ub;
        if (b > a) {
            total += nurbs_gauss_length(c, a, b, lo, hi);
            a = b;
        }
        span++;
    }
    if (a < ub) total += nurbs_gauss_length(c, a, ub, lo, hi);
    return total;
}
