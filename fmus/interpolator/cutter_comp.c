/* Cutter radius compensation (G40/G41/G42) after parsing: see cutter_comp.h and the Python reference
 * models/interpolator/cutter_comp.py, which this file follows operation for operation (bit-equal moves). */
#include "cutter_comp.h"

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

typedef struct {
    const char *text;
    size_t length;
    const char *file;
    char *error;
    size_t error_size;
} Context;

/* One XY element of a compensated run (see _Element in the Python reference). */
typedef struct {
    int present;
    int arc, rapid;
    size_t index;
    double p0[2], t0[2], t1[2], s[2], e[2];
    double c[2], sigma, ra, rb, ang_s, ang_e, span; /* arcs */
    int has_corner;
    GcMove corner; /* the arc (before a rapid: the rapid) inserted before this element's move */
} Element;

static int fail(const Context *ctx, int line, const char *expected) {
    gc_line_error(ctx->text, ctx->length, ctx->file, line > 0 ? (size_t)line : 0, expected, ctx->error,
                  ctx->error_size);
    return -1;
}

static double wrap(double a) {
    while (a > PI) a -= 2.0 * PI;
    while (a <= -PI) a += 2.0 * PI;
    return a;
}

/* +1 left / -1 right / 0 off, and the radius (>= 0); a negative radius swaps the side */
static int comp_side(const GcMove *m, double *radius) {
    int side;
    double r;
    *radius = 0.0;
    if (m->comp == COMP_LEFT)
        side = 1;
    else if (m->comp == COMP_RIGHT)
        side = -1;
    else
        return 0;
    r = m->comp_radius;
    if (r == 0.0) return 0;
    if (r < 0.0) {
        *radius = -r;
        return -side;
    }
    *radius = r;
    return side;
}

static int xy_motion(const GcMove *m) {
    if (m->kind == MOVE_LINE || m->kind == MOVE_RAPID) return m->end[0] != m->start[0] || m->end[1] != m->start[1];
    return m->kind == MOVE_ARC || m->kind == MOVE_NURBS;
}

/* (angle of x about the arc's centre, its signed step from reference along the sweep) */
static double angle_step(const Element *el, const double x[2], double reference, double *angle) {
    *angle = atan2(x[1] - el->c[1], x[0] - el->c[0]);
    return el->sigma * wrap(*angle - reference);
}

static void set_start(Element *el, const double x[2]) {
    if (el->arc) {
        double a, d = angle_step(el, x, el->ang_s, &a);
        el->span = el->span - d;
        el->ang_s = a;
    }
    el->s[0] = x[0], el->s[1] = x[1];
}

static void set_end(Element *el, const double x[2]) {
    if (el->arc) {
        double a, d = angle_step(el, x, el->ang_e, &a);
        el->span = el->span + d;
        el->ang_e = a;
    }
    el->e[0] = x[0], el->e[1] = x[1];
}

static void element_init(Element *el, size_t index, const GcMove *m, int side, double r) {
    memset(el, 0, sizeof *el);
    el->present = 1;
    el->index = index;
    el->arc = m->kind == MOVE_ARC;
    el->rapid = m->kind == MOVE_RAPID;
    el->p0[0] = m->start[0], el->p0[1] = m->start[1];
    if (el->arc) {
        double rk, theta1 = m->theta0 + m->sweep, u0[2], u1[2], s[2], e[2];
        el->c[0] = m->center[0], el->c[1] = m->center[1];
        el->sigma = m->sweep > 0.0 ? 1.0 : -1.0;
        rk = r * (-(double)side * el->sigma);
        el->ra = m->r0 + rk;
        el->rb = m->r1 + rk;
        u0[0] = cos(m->theta0), u0[1] = sin(m->theta0);
        u1[0] = cos(theta1), u1[1] = sin(theta1);
        el->t0[0] = -el->sigma * u0[1], el->t0[1] = el->sigma * u0[0];
        el->t1[0] = -el->sigma * u1[1], el->t1[1] = el->sigma * u1[0];
        s[0] = m->start[0] + rk * u0[0], s[1] = m->start[1] + rk * u0[1];
        e[0] = m->end[0] + rk * u1[0], e[1] = m->end[1] + rk * u1[1];
        el->ang_s = m->theta0;
        el->ang_e = theta1;
        el->span = fabs(m->sweep);
        set_start(el, s);
        set_end(el, e);
    } else {
        double dx = m->end[0] - m->start[0], dy = m->end[1] - m->start[1];
        double length = sqrt(dx * dx + dy * dy), n[2];
        el->t0[0] = dx / length, el->t0[1] = dy / length;
        el->t1[0] = el->t0[0], el->t1[1] = el->t0[1];
        n[0] = -el->t0[1] * (double)side, n[1] = el->t0[0] * (double)side;
        el->s[0] = m->start[0] + r * n[0], el->s[1] = m->start[1] + r * n[1];
        el->e[0] = m->end[0] + r * n[0], el->e[1] = m->end[1] + r * n[1];
    }
}

/* the intersections of the line q + s t (t unit) with the circle (c, radius), the one nearer q first; returns
 * how many (0 or 2) */
static int line_circle(const double q[2], const double t[2], const double c[2], double radius, double x[2][2]) {
    double wx = q[0] - c[0], wy = q[1] - c[1];
    double b = wx * t[0] + wy * t[1];
    double cc = wx * wx + wy * wy - radius * radius;
    double disc = b * b - cc, sq, s1, s2;
    if (disc < 0.0) return 0;
    sq = sqrt(disc);
    s1 = -b - sq, s2 = -b + sq;
    if (!(fabs(s1) <= fabs(s2))) {
        double swap = s1;
        s1 = s2, s2 = swap;
    }
    x[0][0] = q[0] + s1 * t[0], x[0][1] = q[1] + s1 * t[1];
    x[1][0] = q[0] + s2 * t[0], x[1][1] = q[1] + s2 * t[1];
    return 2;
}

/* the intersections of the circles (c1, r1) and (c2, r2), the one nearer the point near first; how many (0, 2) */
static int circle_circle(const double c1[2], double r1, const double c2[2], double r2, const double near[2],
                         double x[2][2]) {
    double dx = c2[0] - c1[0], dy = c2[1] - c1[1];
    double d2 = dx * dx + dy * dy, d, a, h2, h, ux, uy, bx, by, x1[2], x2[2], e1x, e1y, e2x, e2y;
    int first;
    if (d2 <= 0.0) return 0;
    d = sqrt(d2);
    a = (r1 * r1 - r2 * r2 + d2) / (2.0 * d);
    h2 = r1 * r1 - a * a;
    if (h2 < 0.0) return 0;
    h = sqrt(h2);
    ux = dx / d, uy = dy / d;
    bx = c1[0] + a * ux, by = c1[1] + a * uy;
    x1[0] = bx - h * uy, x1[1] = by + h * ux;
    x2[0] = bx + h * uy, x2[1] = by - h * ux;
    e1x = x1[0] - near[0], e1y = x1[1] - near[1];
    e2x = x2[0] - near[0], e2y = x2[1] - near[1];
    first = e1x * e1x + e1y * e1y <= e2x * e2x + e2y * e2y;
    memcpy(x[0], first ? x1 : x2, sizeof x1);
    memcpy(x[1], first ? x2 : x1, sizeof x1);
    return 2;
}

/* where the offset elements a (ending at the corner p) and b (starting there) intersect, the intersection nearer
 * the junction first; returns how many */
static int meet(const Element *a, const Element *b, const double p[2], int side, double r, double x[2][2]) {
    if (!a->arc && !b->arc) {
        double den = 1.0 + (a->t1[0] * b->t0[0] + a->t1[1] * b->t0[1]), q, nx, ny;
        if (den <= 0.0) return 0;
        q = r / den;
        nx = -a->t1[1] * (double)side + -b->t0[1] * (double)side;
        ny = a->t1[0] * (double)side + b->t0[0] * (double)side;
        x[0][0] = p[0] + q * nx, x[0][1] = p[1] + q * ny;
        return 1;
    }
    if (!a->arc) return line_circle(a->e, a->t1, b->c, b->ra, x);
    if (!b->arc) return line_circle(b->s, b->t0, a->c, a->rb, x);
    return circle_circle(a->c, a->rb, b->c, b->ra, a->e, x);
}

/* whether x joins a to b: both keep a positive length, and x shortens a at its end and b at its start (inside
 * corners) or lengthens them (outside corners), allowing COMP_SLACK the other way */
static int fits(const Element *a, const Element *b, const double x[2], int inside) {
    double sign = inside ? 1.0 : -1.0, angle, d;
    if (a->arc) {
        d = angle_step(a, x, a->ang_e, &angle);
        if (sign * d * a->rb > COMP_SLACK || !(a->span + d > 0.0)) return 0;
    } else {
        if (sign * ((x[0] - a->e[0]) * a->t1[0] + (x[1] - a->e[1]) * a->t1[1]) > COMP_SLACK) return 0;
        if (!((x[0] - a->s[0]) * a->t1[0] + (x[1] - a->s[1]) * a->t1[1] > 0.0)) return 0;
    }
    if (b->arc) {
        d = angle_step(b, x, b->ang_s, &angle);
        if (sign * d * b->ra < -COMP_SLACK || !(b->span - d > 0.0)) return 0;
    } else {
        if (sign * ((x[0] - b->s[0]) * b->t0[0] + (x[1] - b->s[1]) * b->t0[1]) < -COMP_SLACK) return 0;
        if (!((b->e[0] - x[0]) * b->t0[0] + (b->e[1] - x[1]) * b->t0[1] > 0.0)) return 0;
    }
    return 1;
}

/* joins a (ending at the programmed corner) to b (starting there) */
static int corner(const Context *ctx, Element *a, Element *b, const GcMove *move_a, const GcMove *move_b, int side,
                  double r) {
    const double *ta = a->t1, *tb = b->t0, *p = b->p0;
    double cross = ta[0] * tb[1] - ta[1] * tb[0];
    double dot = ta[0] * tb[0] + ta[1] * tb[1];
    double x[2][2], sweep, z, theta0;
    int tangent = fabs(cross) <= COMP_TANGENT, n, k;
    GcMove *arc;
    if (tangent && dot > 0.0) {
        set_start(b, a->e);
        return 0;
    }
    if ((double)side * cross > 0.0 && !tangent) {
        char expected[160];
        n = meet(a, b, p, side, r, x);
        for (k = 0; k < n; k++)
            if (fits(a, b, x[k], 1)) {
                set_end(a, x[k]);
                set_start(b, x[k]);
                return 0;
            }
        snprintf(expected, sizeof expected, "the tool (radius %.6g mm) cannot follow this inside corner without "
                 "gouging", r * 1000.0);
        return fail(ctx, move_a->line, expected);
    }
    if (dot > 0.0 && fabs(cross) < COMP_SMALL_TURN) {
        n = meet(a, b, p, side, r, x);
        for (k = 0; k < n; k++) {
            double ex = x[k][0] - p[0], ey = x[k][1] - p[1];
            if (ex * ex + ey * ey <= 4.0 * r * r && fits(a, b, x[k], 0)) {
                set_end(a, x[k]);
                set_start(b, x[k]);
                return 0;
            }
        }
    }
    z = move_b->start[2];
    arc = &b->corner;
    *arc = *move_b;
    b->has_corner = 1;
    if (b->rapid) {
        arc->start[0] = a->e[0], arc->start[1] = a->e[1], arc->start[2] = z;
        arc->end[0] = b->s[0], arc->end[1] = b->s[1], arc->end[2] = z;
        arc->exact_stop = 0;
        arc->dwell = 0.0;
        return 0;
    }
    sweep = fabs(cross) > COMP_TANGENT ? atan2(cross, dot) : -(double)side * PI;
    theta0 = atan2(a->e[1] - p[1], a->e[0] - p[0]);
    arc->kind = MOVE_ARC;
    arc->start[0] = a->e[0], arc->start[1] = a->e[1], arc->start[2] = z;
    arc->end[0] = b->s[0], arc->end[1] = b->s[1], arc->end[2] = z;
    arc->center[0] = p[0], arc->center[1] = p[1], arc->center[2] = z;
    arc->axes[0] = 0, arc->axes[1] = 1, arc->axes[2] = 2;
    arc->theta0 = theta0;
    arc->sweep = sweep;
    arc->r0 = r, arc->r1 = r;
    arc->height = 0.0;
    arc->curve = -1;
    arc->u0 = 0.0, arc->u1 = 0.0;
    arc->exact_stop = 0;
    arc->dwell = 0.0;
    return 0;
}

/* the elements of the compensated run moves[first, last) (els[k - first]), entered from the tool position cur */
static int plan(const Context *ctx, const GcProgram *program, size_t first, size_t last, const double cur[2],
                int side, double r, Element *els) {
    Element *previous = NULL;
    size_t k;
    char expected[256];
    for (k = first; k < last; k++) {
        const GcMove *m = &program->moves[k];
        Element *el = &els[k - first];
        el->present = 0;
        if (m->kind == MOVE_NURBS)
            return fail(ctx, m->line, "cutter compensation of a NURBS block is not supported (G40 before the block)");
        if (m->kind == MOVE_ARC && !(m->axes[0] == 0 && m->axes[1] == 1 && m->axes[2] == 2)) {
            snprintf(expected, sizeof expected, "cutter compensation in the XY plane (G17) only (the tool radius "
                     "offsets the path within XY), this arc lies in the %s",
                     m->axes[0] == 1 && m->axes[1] == 2 && m->axes[2] == 0 ? "YZ plane (G19)" : "ZX plane (G18)");
            return fail(ctx, m->line, expected);
        }
        if (!xy_motion(m)) continue;
        if (!previous) {
            GcMove entry;
            double dx, dy, distance;
            if (m->kind == MOVE_ARC)
                return fail(ctx, m->line, "a straight entry move (G0 or G1) as the first move in XY after G41/G42, "
                            "got an arc");
            dx = m->end[0] - cur[0], dy = m->end[1] - cur[1];
            distance = sqrt(dx * dx + dy * dy);
            if (!(distance > r)) {
                snprintf(expected, sizeof expected, "an entry move after G41/G42 longer than the tool radius "
                         "(%.6g mm): the tool would cover the programmed point", r * 1000.0);
                return fail(ctx, m->line, expected);
            }
            entry = *m;
            entry.start[0] = cur[0], entry.start[1] = cur[1];
            element_init(el, k, &entry, side, r);
            el->s[0] = cur[0], el->s[1] = cur[1];
        } else {
            element_init(el, k, m, side, r);
            if (el->arc && !(el->ra > 0.0 && el->rb > 0.0)) {
                snprintf(expected, sizeof expected, "an arc radius greater than the tool radius (%.6g mm) on the "
                         "compensated side (the tool cannot follow a radius of %.6g mm without gouging)", r * 1000.0,
                         (m->r1 < m->r0 ? m->r1 : m->r0) * 1000.0);
                el->present = 0;
                return fail(ctx, m->line, expected);
            }
            if (corner(ctx, previous, el, &program->moves[previous->index], m, side, r) != 0) return -1;
        }
        previous = el;
    }
    return 0;
}

static void keep_xy(GcMove *out, const GcMove *m, const double cur[2]) {
    *out = *m;
    out->start[0] = cur[0], out->start[1] = cur[1];
    out->end[0] = cur[0], out->end[1] = cur[1];
}

/* 1 when compensating would change nothing: no move is compensated and every move without XY motion already stands
 * where the XY moves before it ended (what keep_xy sets), so the copy below would equal the program. */
static int unchanged(const GcProgram *program) {
    double cur[2], r;
    size_t i;
    cur[0] = program->start[0], cur[1] = program->start[1];
    for (i = 0; i < program->n_moves; i++) {
        const GcMove *m = &program->moves[i];
        if (comp_side(m, &r) != 0) return 0;
        if (!xy_motion(m)) {
            if (m->start[0] != cur[0] || m->start[1] != cur[1] || m->end[0] != cur[0] || m->end[1] != cur[1])
                return 0;
        } else {
            cur[0] = m->end[0], cur[1] = m->end[1];
        }
    }
    return 1;
}

int cutter_compensate(GcProgram *program, const char *text, size_t length, const char *file, char *error,
                      size_t error_size) {
    Context ctx;
    size_t n = program->n_moves, i = 0, count = 0, cap;
    GcMove *out;
    Element *els;
    double cur[2];
    int closing = 0;
    ctx.text = text, ctx.length = length, ctx.file = file, ctx.error = error, ctx.error_size = error_size;
    if (n == 0 || unchanged(program)) return 0; /* (a program without G41/G42: no copy of its moves) */
    if (n > SIZE_MAX / 2 / sizeof *out) {
        snprintf(error, error_size, "%s: out of memory for the compensated moves", file);
        return -1;
    }
    cap = 2 * n;
    out = malloc(cap * sizeof *out);
    els = malloc(n * sizeof *els);
    if (!out || !els) {
        free(out);
        free(els);
        snprintf(error, error_size, "%s: out of memory for %zu compensated moves", file, cap);
        return -1;
    }
    cur[0] = program->start[0], cur[1] = program->start[1];
    while (i < n) {
        const GcMove *m = &program->moves[i];
        double r;
        int side = comp_side(m, &r);
        if (side != 0) {
            size_t j = i + 1, k;
            int any = 0;
            double rj;
            while (j < n && comp_side(&program->moves[j], &rj) != 0) {
                if (program->moves[j].comp != m->comp || program->moves[j].comp_radius != m->comp_radius) {
                    fail(&ctx, program->moves[j].line, "G40 before changing the side or the radius of an active "
                         "cutter compensation (G41/G42 with another D)");
                    goto failed;
                }
                j++;
            }
            if (plan(&ctx, program, i, j, cur, side, r, els) != 0) goto failed;
            for (k = i; k < j; k++) {
                const GcMove *mk = &program->moves[k];
                const Element *el = &els[k - i];
                GcMove *o;
                if (!el->present) {
                    keep_xy(&out[count++], mk, cur);
                    continue;
                }
                any = 1;
                if (el->has_corner) out[count++] = el->corner;
                o = &out[count++];
                *o = *mk;
                o->start[0] = el->s[0], o->start[1] = el->s[1];
                o->end[0] = el->e[0], o->end[1] = el->e[1];
                if (el->arc) {
                    double sx = el->s[0] - el->c[0], sy = el->s[1] - el->c[1];
                    double ex = el->e[0] - el->c[0], ey = el->e[1] - el->c[1];
                    o->theta0 = el->ang_s;
                    o->sweep = el->sigma * el->span;
                    o->r0 = sqrt(sx * sx + sy * sy);
                    o->r1 = sqrt(ex * ex + ey * ey);
                }
                cur[0] = el->e[0], cur[1] = el->e[1];
            }
            if (any) closing = 1;
            i = j;
            continue;
        }
        if (!xy_motion(m)) {
            keep_xy(&out[count++], m, cur);
        } else if (closing) {
            if (m->kind != MOVE_LINE && m->kind != MOVE_RAPID) {
                fail(&ctx, m->line,
                     m->kind == MOVE_ARC
                         ? "a straight exit move (G0 or G1) as the first move in XY after G40, got an arc"
                         : "a straight exit move (G0 or G1) as the first move in XY after G40, got a NURBS block");
                goto failed;
            }
            closing = 0;
            if (cur[0] != m->end[0] || cur[1] != m->end[1] || m->start[2] != m->end[2]) {
                GcMove *o = &out[count++];
                *o = *m;
                o->start[0] = cur[0], o->start[1] = cur[1];
            }
            cur[0] = m->end[0], cur[1] = m->end[1];
        } else {
            out[count++] = *m;
            cur[0] = m->end[0], cur[1] = m->end[1];
        }
        i++;
    }
    free(els);
    free(program->moves);
    program->moves = out;
    program->n_moves = count;
    program->cap_moves = cap;
    return 0;
failed:
    free(els);
    free(out);
    return -1;
}
