/* Workpiece: a Z-map of the stock block cut by a flat, bull-nose or ball end mill (models/workpiece.py
 * describes the algorithm; models.workpiece.ZMap is the same in numpy, operation for operation, and the
 * tests compare the two to the last bit). Per step: remove the material under the tool swept from the
 * previous to the current tool tip position, visiting only the cells under the swept tool, then
 * compute the engagement at the new position: depths, entry and exit angles, MRR and the map. Both
 * leave out work that provably cannot change their result (cells already cleared, probes of the
 * stock that still fall in the same cells: remove_segment(), engagement()), so a slow feed stepped
 * finely costs little, and the outputs stay those of the reference to the last bit. */
#include <errno.h>
#include <float.h>
#include <locale.h>
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "fmu_instance.h"

/* PI, MAX_CELLS (memory cap: 160 MB of heights), MIN_CELLS_ACROSS_TOOL, DESCEND_PER_SUBSEGMENT and
 * FEED_DIRECTION_MIN_TRAVEL (times delta), SPINDLE_STOPPED (rad/s: 1 rpm): model_constants.h, from models/ */

/* the map is one row-major array of N_Z x N_THETA values (models.workpiece: shape of "engagement") */
typedef char map_size_matches_the_model[(SIZE_engagement == N_Z * N_THETA) ? 1 : -1];

static double cell_count(double size, double resolution) { return ceil(size / resolution - 1e-6); }

/* fmin/fmax without the library call, for operands that cannot be NaN (the step's inputs are finite) */
static double min2(double a, double b) { return b < a ? b : a; }
static double max2(double a, double b) { return b > a ? b : a; }
static double clamp(double u, double lo, double hi) { return max2(min2(u, hi), lo); }

/* floor and ceil of a value within the grid's index range (|u| < 2^31): without the library's handling of
 * any double, which the per-row bounds of the removal spent half their time in */
static double floor_index(double u) {
    const double t = (double)(long)u;
    return t > u ? t - 1.0 : t;
}
static double ceil_index(double u) {
    const double t = (double)(long)u;
    return t < u ? t + 1.0 : t;
}
static size_t index_of(double u) { return (size_t)(long)u; } /* u: an index of the grid, so >= 0 and < 2^31 */

/* The finest resolution whose grid (cells rounded up per side) fits MAX_CELLS, with a margin. */
static double finest_resolution(double length, double width) {
    const double even = sqrt(length * width / MAX_CELLS);
    return even * (1.0 + ((length + width) / even + 1.0) / MAX_CELLS);
}

/* Cutter radius at `height` above the tip. */
static double radius_at(const ModelInternal *w, double height) {
    double rise;
    if (height >= w->corner) return w->radius;
    rise = w->corner - height;
    return w->flat + sqrt(fmax(w->corner * w->corner - rise * rise, 0.0));
}

/* Angle sample m of the front half: m / n_angles of pi (exactly 0 and pi at the ends). */
static double angle(const ModelInternal *w, size_t m) { return (double)m / (double)w->n_angles * PI; }

/* The checks of the tool against the stock and the grid (models.workpiece.validate_tool): at initialization and
 * at a tool change; `where` starts the message ("exitInitializationMode", "doStep: t = 1 s: tool change"). */
static FmuStatus check_tool(FmuInstance *instance, const char *where) {
    const ModelVariables *v = &instance->v;
    if (v->corner_radius > 0.5 * v->tool_diameter) {
        fmu_log(instance, FMU_ERROR, "logStatusError",
                "%s: corner_radius = %g m is larger than tool_diameter/2 = %g m (0: flat end mill, "
                "tool_diameter/2: ball end mill)", where, v->corner_radius, 0.5 * v->tool_diameter);
        return FMU_ERROR;
    }
    if (v->tool_diameter > v->stock_length || v->tool_diameter > v->stock_width) {
        fmu_log(instance, FMU_ERROR, "logStatusError",
                "%s: the tool is larger than the stock: tool_diameter = %g m, stock_length = %g m, stock_width = "
                "%g m", where, v->tool_diameter, v->stock_length, v->stock_width);
        return FMU_ERROR;
    }
    if (v->tool_diameter < MIN_CELLS_ACROSS_TOOL * v->resolution) {
        fmu_log(instance, FMU_ERROR, "logStatusError",
                "%s: resolution = %g m is too coarse for tool_diameter = %g m: the Z-map needs at least %g cells "
                "across the tool (resolution <= %g m)", where, v->resolution, v->tool_diameter,
                MIN_CELLS_ACROSS_TOOL, v->tool_diameter / MIN_CELLS_ACROSS_TOOL);
        return FMU_ERROR;
    }
    return FMU_OK;
}

/* The tool from tool_diameter, corner_radius and tool_length (checked: check_tool()): its geometry in w and its
 * tables in the heap after the nx * ny heights, the heap resized to fit and the heights kept. At initialization
 * and at a tool change (models.workpiece.ZMap._derive_tool). Nothing changes when the heap cannot be resized. */
static FmuStatus derive_tool(FmuInstance *instance, const char *function) {
    const ModelVariables *v = &instance->v;
    ModelInternal *w = &instance->internal;
    const double radius = 0.5 * v->tool_diameter, corner = v->corner_radius;
    const size_t n_angles = (size_t)ceil(PI * radius / w->delta);
    const size_t n_corner = corner > 0.0 ? (size_t)ceil(0.5 * PI * corner / w->delta) : 0;
    const size_t cells = w->nx * w->ny;
    double arc, *heap;
    size_t k;
    if (fmu_resize_heap(instance, function, cells + 2 * (n_angles + 1) + 2 * (n_corner + 1)) != FMU_OK)
        return FMU_ERROR;
    w->tool_diameter = v->tool_diameter;
    w->corner_radius = v->corner_radius;
    w->tool_length = v->tool_length;
    w->radius = radius;
    w->corner = corner;
    w->flat = w->radius - w->corner;
    w->arc_margin = w->half_diagonal + 2.0 * w->delta * (1.0 + 0.5 * w->delta / w->radius);
    w->n_angles = n_angles;
    w->n_corner = n_corner;
    w->cos_phi = cells;
    w->sin_phi = w->cos_phi + w->n_angles + 1;
    w->profile_z = w->sin_phi + w->n_angles + 1;
    w->profile_r = w->profile_z + w->n_corner + 1;
    heap = instance->heap;
    for (k = 0; k <= w->n_angles; k++) {
        heap[w->cos_phi + k] = cos(angle(w, k));
        heap[w->sin_phi + k] = sin(angle(w, k));
    }
    arc = w->n_corner ? 0.5 * PI / (double)w->n_corner : 0.0;
    for (k = 0; k < w->n_corner; k++) {
        heap[w->profile_z + k] = w->corner * (1.0 - cos((double)k * arc));
        heap[w->profile_r + k] = w->flat + w->corner * sin((double)k * arc);
    }
    heap[w->profile_z + w->n_corner] = w->corner;
    heap[w->profile_r + w->n_corner] = w->radius;
    return FMU_OK;
}

/* Nothing reused from earlier steps: at initialization, and at a tool change, where each would be wrong for the
 * new tool (all are exact only for the tool they were made with). */
static void forget_reuse(ModelInternal *w) {
    size_t k;
    /* the cleared disc: cells within the old radius of its centre lie at or below a level computed with the old
     * corner; a larger or rounder tool would skip cells it cuts */
    w->cleared_valid = false;
    /* the probe rooms and what their probes found (scan_first/last are old angle samples, the bisected angles
     * and the outputs the old profile's): the probes lie at the old radius and profile heights */
    w->scan_rooms.valid = w->bisection_rooms.valid = w->map_rooms.valid = false;
    /* the angles of the last bisections and their cos and sin: keyed by the angle alone, so still exact, but
     * the new tool's bisections start from other samples: dropped with the rest */
    for (k = 0; k < N_BISECTIONS; k++) w->bisection_phi[0][k] = w->bisection_phi[1][k] = -1.0;
    /* the cut top: the old tool's cuts, within its R to 2R of travel, do not bound the new tool's engaged
     * height (a larger tool reaches material the old one never cut); the next contact is a first contact */
    w->stretch_top = w->previous_stretch_top = -INFINITY;
    w->stretch_travel = 0.0;
}

FmuStatus model_exit_initialization(FmuInstance *instance) {
    static const char *const function = "exitInitializationMode";
    const ModelVariables *v = &instance->v;
    ModelInternal *w = &instance->internal;
    double nx, ny;
    size_t k;

    if (check_tool(instance, function) != FMU_OK) return FMU_ERROR;
    nx = cell_count(v->stock_length, v->resolution);
    ny = cell_count(v->stock_width, v->resolution);
    if (nx * ny > MAX_CELLS) {
        fmu_log(instance, FMU_ERROR, "logStatusError",
                "%s: resolution = %g m is too fine for the stock: %.0f x %.0f cells, more than the limit of %.0f "
                "cells (%.0f MB); use resolution >= %g m", function, v->resolution, nx, ny, MAX_CELLS,
                MAX_CELLS * 8.0 / 1e6, finest_resolution(v->stock_length, v->stock_width));
        return FMU_ERROR;
    }

    memset(w, 0, sizeof *w);
    w->nx = (size_t)nx;
    w->ny = (size_t)ny;
    w->dx = v->stock_length / nx;
    w->dy = v->stock_width / ny;
    w->delta = fmin(w->dx, w->dy);
    w->half_diagonal = 0.5 * sqrt(w->dx * w->dx + w->dy * w->dy);
    w->top = v->stock_z_min + v->stock_height;
    if (derive_tool(instance, function) != FMU_OK) return FMU_ERROR;
    for (k = 0; k < w->nx * w->ny; k++) instance->heap[k] = w->top;
    w->flute_length = v->flute_length;
    w->x = v->tool_x;
    w->y = v->tool_y;
    w->point_z = v->tool_z;
    w->z = v->tool_z - v->tool_length;
    w->feed_x = 1.0;
    w->feed_y = 0.0;
    forget_reuse(w); /* nothing cut yet, no angle of [0, pi] bisected yet */
    return FMU_OK;
}

/* The first index from i on (before end) of a cell above `level`, else end. Most cells a step visits
 * lie in the slot behind and under the tool, at or below the lowest it reaches: four compared at a
 * time, without a branch per cell. */
static inline size_t next_above(const double *row, size_t i, size_t end, double level) {
    while (i + 4 <= end && !((row[i] > level) | (row[i + 1] > level) | (row[i + 2] > level) | (row[i + 3] > level)))
        i += 4;
    while (i < end && !(row[i] > level)) i++;
    return i;
}

/* A straight move of the tool tip from a to b. */
typedef struct {
    const double *a, *b;
    double sx, sy, sz, length2;
    double unreachable; /* the lowest the tool reaches or the stock's bottom: a cell at or below cannot change */
    double *top;        /* the highest height before the cut of the cells lowered so far in the step */
} Segment;

/* Lower the cells [from, end) of the row at cy that are under the tool, exactly as the reference does;
 * returns volume plus their drops, in cell order. */
static double cut_cells(FmuInstance *instance, const Segment *g, double *row, double cy, size_t from, size_t end,
                        double volume) {
    const ModelInternal *w = &instance->internal;
    const double x0 = instance->v.stock_x_min, z0 = instance->v.stock_z_min, r2 = w->radius * w->radius;
    const double *a = g->a, *b = g->b;
    size_t i;
    for (i = next_above(row, from, end, g->unreachable); i < end; i = next_above(row, i + 1, end, g->unreachable)) {
        const double cx = x0 + ((double)i + 0.5) * w->dx;
        double qx, qy, zt, ex, ey, d2, zc;
        if (g->length2 > 0.0) { /* the point of the segment closest to the cell centre */
            double t = ((cx - a[0]) * g->sx + (cy - a[1]) * g->sy) / g->length2;
            if (t < 0.0)
                t = 0.0;
            else if (t > 1.0)
                t = 1.0;
            qx = a[0] + t * g->sx;
            qy = a[1] + t * g->sy;
            zt = a[2] + t * g->sz;
        } else { /* a vertical move: the lowest position */
            qx = a[0];
            qy = a[1];
            zt = min2(a[2], b[2]);
        }
        ex = cx - qx;
        ey = cy - qy;
        d2 = ex * ex + ey * ey;
        if (d2 > r2) continue;
        zc = zt;
        if (w->corner > 0.0 && d2 > w->flat * w->flat) {
            const double e = sqrt(d2) - w->flat;
            zc = zt + (w->corner - sqrt(max2(w->corner * w->corner - e * e, 0.0)));
        }
        if (zc < z0) zc = z0;
        if (zc < row[i]) {
            volume += row[i] - zc;
            if (row[i] > *g->top) *g->top = row[i];
            row[i] = zc;
        }
    }
    return volume;
}

/* Lower the cells under the tool moved in a straight line from a to b; returns volume plus the sum of
 * the height drops (in cell order: the reference sums in the same order). Cells that cannot change
 * are not computed (the others exactly as the reference does, so the result is the same): those
 * of a row beyond the tool's reach (the row's cells within r of the segment lie within
 * sqrt(r^2 - dy^2) of its x extent, dy the row's distance from its y extent), those already at or
 * below the lowest the tool reaches here (the lower end of the segment) or the stock's bottom, and
 * those of the disc the last segment cleared to that height or lower (the tool at rest or moving a
 * fraction of a cell per step visits little else). Distances have a margin of delta/16 (at least
 * 0.5 um): their rounding is below 1e-7 m, even with coordinates of 10 m and a 0.1 m tool. */
static double remove_segment(FmuInstance *instance, const double a[3], const double b[3], double volume, double *top) {
    ModelInternal *w = &instance->internal;
    const double x0 = instance->v.stock_x_min, y0 = instance->v.stock_y_min, z0 = instance->v.stock_z_min;
    const double r = w->radius, r2 = r * r;
    const double x_min = min2(a[0], b[0]), x_max = max2(a[0], b[0]), y_min = min2(a[1], b[1]), y_max = max2(a[1], b[1]);
    const double margin = w->delta / 16.0, per_dx = 1.0 / w->dx;
    const double inner = r - 3.0 * margin; /* cells within it of the cleared centre: within r - 2 margin */
    Segment g;
    bool skip_cleared;
    double cleared_x, cleared_y; /* the disc the last segment left */
    double i_lo, i_hi, j_lo, j_hi, jd;
    g.a = a;
    g.b = b;
    g.top = top;
    g.sx = b[0] - a[0];
    g.sy = b[1] - a[1];
    g.sz = b[2] - a[2];
    g.length2 = g.sx * g.sx + g.sy * g.sy;
    /* the lowest tip height computed in cut_cells: a[2] + t*sz with t in [0, 1] is at least a[2] + sz (rounding
     * is monotonic), or min(a[2], b[2]) for a vertical move; a corner only adds corner - sqrt(...) >= 0 */
    g.unreachable = max2(min2(min2(a[2], b[2]), a[2] + g.sz), z0);
    skip_cleared = w->cleared_valid && w->cleared_level <= g.unreachable;
    cleared_x = w->cleared_x;
    cleared_y = w->cleared_y;
    /* what this segment leaves: every cell within r - 2 margin of b was computed (rounding is far below the
     * margin) and lowered to the tool's surface there, the tip at most max(a[2], a[2] + sz, b[2]) (as above)
     * and a corner adding at most corner; or it was at or below `unreachable` already */
    w->cleared_valid = true;
    w->cleared_x = b[0];
    w->cleared_y = b[1];
    w->cleared_level = max2(max2(max2(a[2], b[2]), a[2] + g.sz), z0);
    if (w->corner > 0.0) w->cleared_level = max2(w->cleared_level + w->corner, z0);
    if (min2(a[2], b[2]) >= w->top) return volume; /* above the stock: nothing to cut */
    /* the box of the reference (models.workpiece.ZMap._remove_segment), computed as it does */
    i_lo = max2(floor((x_min - r - x0) / w->dx - 0.5), 0.0);
    i_hi = min2(ceil((x_max + r - x0) / w->dx - 0.5), (double)w->nx - 1.0);
    j_lo = max2(floor((y_min - r - y0) / w->dy - 0.5), 0.0);
    j_hi = min2(ceil((y_max + r - y0) / w->dy - 0.5), (double)w->ny - 1.0);
    if (i_lo > i_hi || j_lo > j_hi) return volume; /* beside the stock */
    /* bounds clamped to one beyond the box: the same cells, and within the range of floor_index, ceil_index */
    for (jd = j_lo; jd <= j_hi; jd += 1.0) {
        const double cy = y0 + (jd + 0.5) * w->dy;
        const double dy = cy < y_min ? y_min - cy : (cy > y_max ? cy - y_max : 0.0);
        const double reach = sqrt(max2(r2 - dy * dy, 0.0)) + margin;
        /* the cells whose centres lie within reach of the x extent */
        const double row_lo =
            max2(ceil_index(clamp((x_min - reach - x0) * per_dx - 0.5, i_lo - 1.0, i_hi + 1.0)), i_lo);
        const double row_hi =
            min2(floor_index(clamp((x_max + reach - x0) * per_dx - 0.5, i_lo - 1.0, i_hi + 1.0)), i_hi);
        double *row = instance->heap + index_of(jd) * w->nx;
        double from[2], end[2];
        int piece;
        if (dy > r + margin || row_lo > row_hi) continue;
        from[0] = row_lo; /* the row without the cleared cells [end[0], from[1]) */
        end[0] = from[1] = end[1] = row_hi + 1.0;
        if (skip_cleared) {
            const double dc = cy - cleared_y;
            if (dc * dc < inner * inner) {
                const double half = sqrt(inner * inner - dc * dc);
                const double skip_lo = ceil_index(clamp((cleared_x - half - x0) * per_dx - 0.5, row_lo, end[1]));
                const double skip_end =
                    floor_index(clamp((cleared_x + half - x0) * per_dx - 0.5, row_lo - 1.0, row_hi)) + 1.0;
                if (skip_lo < skip_end) {
                    end[0] = skip_lo;
                    from[1] = skip_end;
                }
            }
        }
        for (piece = 0; piece < 2; piece++)
            if (from[piece] < end[piece])
                volume = cut_cells(instance, &g, row, cy, index_of(from[piece]), index_of(end[piece]), volume);
    }
    return volume;
}

/* The move of one step, in sub-segments that descend at most DESCEND_PER_SUBSEGMENT * delta each
 * (one for a move without horizontal travel). Returns the sum of the height drops; raises *top to the highest
 * height before the cut of the cells lowered. */
static double remove_material(FmuInstance *instance, const double start[3], const double end[3], double *top) {
    const double sx = end[0] - start[0], sy = end[1] - start[1], sz = end[2] - start[2];
    double volume = 0.0, a[3], b[3], n = 1.0, k;
    if (sx * sx + sy * sy > 0.0)
        n = max2(1.0, ceil(fabs(sz) / (DESCEND_PER_SUBSEGMENT * instance->internal.delta)));
    memcpy(a, start, sizeof a);
    for (k = 1.0; k <= n; k += 1.0) {
        if (k == n) {
            memcpy(b, end, sizeof b);
        } else {
            const double f = k / n;
            b[0] = start[0] + sx * f;
            b[1] = start[1] + sy * f;
            b[2] = start[2] + sz * f;
        }
        volume = remove_segment(instance, a, b, volume, top);
        memcpy(a, b, sizeof a);
    }
    return volume;
}

/* A set of probes about to be made with the tool at (x, y): no room taken yet. */
static void start_rooms(ProbeRooms *rooms, double x, double y) {
    rooms->valid = true;
    rooms->x = x;
    rooms->y = y;
    rooms->x_minus = rooms->x_plus = rooms->y_minus = rooms->y_plus = INFINITY;
}

/* Whether every probe of `rooms` stays in its cell with the tool at its current position, so gives the
 * same height. A probe is the tool position plus an offset that depends only on the feed and the angle,
 * so it moves with the tool up to rounding: a few ulp of the coordinates, relative to a cell below
 * 1e-8 by the ranges of the variables; `slack` allows 4 times the worst case. A coordinate that did
 * not change moves no probe at all. */
static bool rooms_hold(const FmuInstance *instance, const ProbeRooms *rooms) {
    const ModelInternal *w = &instance->internal;
    const double reach = w->radius + w->delta; /* of the farthest probe from the tool */
    double shift, slack;
    if (!rooms->valid) return false;
    if (w->x != rooms->x) {
        shift = (w->x - rooms->x) / w->dx;
        slack = 16.0 * DBL_EPSILON * (fabs(w->x) + fabs(rooms->x) + 2.0 * (fabs(instance->v.stock_x_min) + reach)) /
                w->dx;
        if (!(shift < rooms->x_plus - slack && -shift < rooms->x_minus - slack)) return false;
    }
    if (w->y != rooms->y) {
        shift = (w->y - rooms->y) / w->dy;
        slack = 16.0 * DBL_EPSILON * (fabs(w->y) + fabs(rooms->y) + 2.0 * (fabs(instance->v.stock_y_min) + reach)) /
                w->dy;
        if (!(shift < rooms->y_plus - slack && -shift < rooms->y_minus - slack)) return false;
    }
    return true;
}

/* Stock height at (px, py) minus z; -inf outside the block. The probe's room in its cell narrows `rooms`. */
static double height_above(const FmuInstance *instance, ProbeRooms *rooms, double px, double py, double z) {
    const ModelInternal *w = &instance->internal;
    const double u = (px - instance->v.stock_x_min) / w->dx, fi = floor(u);
    const double v = (py - instance->v.stock_y_min) / w->dy, fj = floor(v);
    rooms->x_minus = min2(rooms->x_minus, u - fi);
    rooms->x_plus = min2(rooms->x_plus, fi + 1.0 - u);
    rooms->y_minus = min2(rooms->y_minus, v - fj);
    rooms->y_plus = min2(rooms->y_plus, fj + 1.0 - v);
    if (!(fi >= 0.0 && fi < (double)w->nx && fj >= 0.0 && fj < (double)w->ny)) return -INFINITY;
    return instance->heap[index_of(fj) * w->nx + index_of(fi)] - z;
}

/* Any profile sample at angle phi in material (the test of scan(), at one angle). The angle is the
 * bisection's `level`th towards the entry (side 0) or exit (side 1): the same as in the last bisection
 * mostly, so its cos and sin are kept. */
static bool engaged_at(FmuInstance *instance, int side, int level, double phi) {
    ModelInternal *w = &instance->internal;
    const double *heap = instance->heap;
    double c, s, ux, uy;
    size_t k;
    if (w->bisection_phi[side][level] != phi) {
        w->bisection_phi[side][level] = phi;
        w->bisection_cos[side][level] = cos(phi);
        w->bisection_sin[side][level] = sin(phi);
    }
    c = w->bisection_cos[side][level];
    s = w->bisection_sin[side][level];
    ux = s * w->feed_x - c * w->feed_y;
    uy = s * w->feed_y + c * w->feed_x;
    for (k = 0; k <= w->n_corner; k++) {
        const double rho = heap[w->profile_r + k] + w->delta;
        const double above = height_above(instance, &w->bisection_rooms, w->x + rho * ux, w->y + rho * uy, w->z);
        if (above > heap[w->profile_z + k]) return true;
    }
    return false;
}

/* The engaged angle next to the boundary between the samples `inside` (engaged) and `outside`. */
static double boundary(FmuInstance *instance, int side, double inside, double outside) {
    int n;
    for (n = 0; n < N_BISECTIONS; n++) {
        const double middle = 0.5 * (inside + outside);
        if (engaged_at(instance, side, n, middle))
            inside = middle;
        else
            outside = middle;
    }
    return inside;
}

/* The angle samples of the front half in runs of consecutive engaged samples: whether a run cuts; then
 * the first and last sample of the cutting runs and the largest engaged height of their cutting points. */
static bool scan(const FmuInstance *instance, ProbeRooms *rooms, size_t *first, size_t *last, double *axial) {
    const ModelInternal *w = &instance->internal;
    const double *heap = instance->heap;
    const double x = w->x, y = w->y, z = w->z, fx = w->feed_x, fy = w->feed_y;
    size_t m = 0, k;
    bool engaged = false;
    *axial = -INFINITY;
    while (m <= w->n_angles) {
        const size_t start = m;
        double run_top = -INFINITY, run_deep = -INFINITY;
        for (; m <= w->n_angles; m++) {
            const double c = heap[w->cos_phi + m], s = heap[w->sin_phi + m];
            const double ux = s * fx - c * fy, uy = s * fy + c * fx;
            double best = -INFINITY, best_deep = -INFINITY; /* the highest engaged height of a cutting point */
            bool in_material = false;
            for (k = 0; k <= w->n_corner; k++) {
                const double rho = heap[w->profile_r + k] + w->delta;
                const double above = height_above(instance, rooms, x + rho * ux, y + rho * uy, z);
                if (above > heap[w->profile_z + k]) {
                    const double lateral = fabs(rho * c);
                    in_material = true;
                    /* a test point beside the cutter's circle (within half a cell diagonal of its radius, or
                     * beyond) only touches a wall: runs without a cutting point are no cut, and the heights
                     * such points see (a wall an earlier pass left at the radius, standing above the layer
                     * now cut) are not engaged heights; nor those within arc_margin of the radius when the
                     * run has points farther in (such a wall along an arc reaches that far in) */
                    if (lateral < heap[w->profile_r + k] - w->half_diagonal) {
                        const double top = k < w->n_corner ? min2(above, heap[w->profile_z + k + 1]) : above;
                        if (top > best) best = top;
                        if (lateral < heap[w->profile_r + k] - w->arc_margin && top > best_deep) best_deep = top;
                    }
                }
            }
            if (!in_material) break;
            if (best > run_top) run_top = best;
            if (best_deep > run_deep) run_deep = best_deep;
        }
        if (m == start) { /* not engaged */
            m++;
            continue;
        }
        if (run_top > -INFINITY) { /* the run has a cutting point */
            const double height = run_deep > -INFINITY ? run_deep : run_top;
            if (!engaged) *first = start;
            engaged = true;
            *last = m - 1;
            if (height > *axial) *axial = height;
        }
    }
    return engaged;
}

static void zero_outputs(FmuInstance *instance) {
    int i;
    for (i = 0; i < N_Z * N_THETA; i++) instance->v.engagement[i] = 0.0;
    instance->v.axial_depth = instance->v.radial_depth = instance->v.entry_angle = instance->v.exit_angle = 0.0;
    instance->internal.map_rooms.valid = false;
}

static bool same_bits(double a, double b) { return memcmp(&a, &b, sizeof a) == 0; }

/* Outputs at the current tool position against the current stock (all 0 when not engaged). `volume`:
 * the step's height drops; `cut_top`: the highest height before the cut of the cells lowered in the current and
 * the previous stretch of travel (-inf: none), which bounds the engaged height (models/workpiece.py, step 2).
 * engagement reads the stock only through height_above(), so the result of a set of probes is reused while no
 * cell was lowered, z and the feed are the same and every probe stays in its cell (rooms_hold()): at 600 mm/min
 * stepped at 10 us the tool moves 1/2500 of a 0.25 mm cell per step, the scan's probes hold for tens of steps. */
static void engagement(FmuInstance *instance, double volume, double cut_top) {
    ModelInternal *w = &instance->internal;
    const double x = w->x, y = w->y, z = w->z, fx = w->feed_x, fy = w->feed_y;
    const double column = 2.0 * PI / N_THETA;
    double axial, entry, leave, r_top, widen, cos_entry, cos_exit, previous_ri = -INFINITY;
    double column_ux[N_THETA], column_uy[N_THETA], height[N_THETA];
    size_t k, n_columns = 0;
    int i, j, columns[N_THETA];
    if (volume > 0.0 || !same_bits(z, w->probed_z) || !same_bits(fx, w->probed_feed_x) ||
        !same_bits(fy, w->probed_feed_y)) {
        w->scan_rooms.valid = w->bisection_rooms.valid = w->map_rooms.valid = false;
        w->probed_z = z;
        w->probed_feed_x = fx;
        w->probed_feed_y = fy;
    }
    if (z >= w->top || !(cut_top > -INFINITY)) { /* above the stock, or no material cut in the window */
        zero_outputs(instance);
        return;
    }
    if (!rooms_hold(instance, &w->scan_rooms)) {
        start_rooms(&w->scan_rooms, x, y);
        w->scan_engaged = scan(instance, &w->scan_rooms, &w->scan_first, &w->scan_last, &w->scan_axial);
    }
    if (!w->scan_engaged) {
        zero_outputs(instance);
        return;
    }
    axial = w->scan_axial;
    if (!(cut_top - z > 0.0)) { /* all it cut lies below the tip: it has risen from its cut */
        zero_outputs(instance);
        return;
    }
    if (cut_top - z < axial) axial = cut_top - z; /* no more than the height of the material the tool cuts */
    if (!rooms_hold(instance, &w->bisection_rooms) || w->bisected_first != w->scan_first ||
        w->bisected_last != w->scan_last) {
        /* its last probes lie within 1/1024 of a sample of a cell's edge: they hold for a few steps */
        start_rooms(&w->bisection_rooms, x, y);
        entry = angle(w, w->scan_first);
        leave = angle(w, w->scan_last);
        if (w->scan_first > 0) entry = boundary(instance, 0, entry, angle(w, w->scan_first - 1));
        if (w->scan_last < w->n_angles) leave = boundary(instance, 1, leave, angle(w, w->scan_last + 1));
        w->bisected_first = w->scan_first;
        w->bisected_last = w->scan_last;
        w->bisected_entry = entry;
        w->bisected_leave = leave;
    }
    entry = w->bisected_entry;
    leave = w->bisected_leave;
    if (rooms_hold(instance, &w->map_rooms) && same_bits(entry, w->outputs_entry) &&
        same_bits(leave, w->outputs_leave) && same_bits(axial, w->outputs_axial))
        return; /* the outputs of the last step */
    /* the test circle is delta outside the cutter: where it meets a wall parallel to the feed, the
     * cutter meets it at the same lateral position */
    r_top = radius_at(w, axial);
    widen = (r_top + w->delta) / r_top;
    cos_entry = fmin(fmax(widen * cos(entry), -1.0), 1.0);
    cos_exit = fmin(fmax(widen * cos(leave), -1.0), 1.0);
    instance->v.axial_depth = axial;
    instance->v.entry_angle = acos(cos_entry);
    instance->v.exit_angle = acos(cos_exit);
    instance->v.radial_depth = r_top * (cos_entry - cos_exit);
    /* the columns inside the cut and their directions, the same for every row */
    for (j = 0; j < N_THETA && ((double)j + 0.5) * column < PI; j++) {
        const double phi = ((double)j + 0.5) * column;
        double c, s;
        if (phi < instance->v.entry_angle || phi > instance->v.exit_angle) continue; /* outside the cut */
        c = cos(phi);
        s = sin(phi);
        columns[n_columns] = j;
        column_ux[n_columns] = s * fx - c * fy;
        column_uy[n_columns] = s * fy + c * fx;
        n_columns++;
    }
    start_rooms(&w->map_rooms, x, y);
    for (i = 0; i < N_Z * N_THETA; i++) instance->v.engagement[i] = 0.0;
    for (i = 0; i < N_Z; i++) {
        const double zi = ((double)i + 0.5) * (axial / N_Z);
        const double ri = radius_at(w, zi) + w->delta;
        if (ri != previous_ri) /* rows on the cylinder (all of a flat end mill) probe the same points */
            for (k = 0; k < n_columns; k++)
                height[k] = height_above(instance, &w->map_rooms, x + ri * column_ux[k], y + ri * column_uy[k], z);
        previous_ri = ri;
        for (k = 0; k < n_columns; k++)
            if (height[k] > zi) instance->v.engagement[i * N_THETA + columns[k]] = 1.0;
    }
    w->outputs_entry = entry;
    w->outputs_leave = leave;
    w->outputs_axial = axial;
}

/* The cells [from, end) of the row whose centres lie ey from the tool axis in y: the smallest distance to
 * their material below `best` (else best), each as the reference computes it. */
static double nearest_in_row(const FmuInstance *instance, const double *row, double ey, size_t from, size_t end,
                             double best) {
    const ModelInternal *w = &instance->internal;
    const double x0 = instance->v.stock_x_min, z0 = instance->v.stock_z_min, x = w->x, z = w->z;
    size_t i;
    for (i = from; i < end; i++) {
        const double h = row[i];
        double ex, gh, gv, d;
        if (!(h > z0)) continue;       /* cut to the bottom: no material */
        gv = z - h;
        if (gv >= best) continue;      /* d >= gv (rounding is monotonic): no nearer */
        gv = gv > 0.0 ? gv : 0.0;
        ex = x0 + ((double)i + 0.5) * w->dx - x;
        gh = sqrt(ex * ex + ey * ey) - w->radius;
        gh = gh > 0.0 ? gh : 0.0;
        d = sqrt(gh * gh + gv * gv);
        if (d < best) best = d;
    }
    return best;
}

/* The clearance (models/workpiece.py, step 3): the smallest distance from the tool, a cylinder of radius R with
 * its flat end at the tip, to the material of the cells, and at most clearance_range. The box of cells is the
 * reference's (models.workpiece.ZMap._clearance); of it, the rows and cells that cannot be nearer than the
 * nearest found so far are left out, the rows from the tool's outwards (the row of the cell centre at or below
 * the axis downwards, then the rows above it upwards): a cell's computed distance is at least its row's gap
 * |ey| - R, rounded as it is computed (rounding is monotonic and sqrt(ey^2) = |ey|), and a row's cells farther
 * than best + R in x (with a margin of delta/16, far above the rounding) are at least best away. */
static double clearance(const FmuInstance *instance) {
    const ModelInternal *w = &instance->internal;
    const ModelVariables *v = &instance->v;
    const double x0 = v->stock_x_min, y0 = v->stock_y_min, x = w->x, y = w->y, r = w->radius;
    const double limit = v->clearance_range, reach = r + limit, margin = w->delta / 16.0;
    double best = limit, i_lo, i_hi, j_lo, j_hi, j_tool, jd;
    int direction;
    if (w->z - w->top >= limit) return limit; /* every cell's gv is at least this */
    i_lo = max2(floor((x - reach - margin - x0) / w->dx - 0.5), 0.0);
    i_hi = min2(ceil((x + reach + margin - x0) / w->dx - 0.5), (double)w->nx - 1.0);
    j_lo = max2(floor((y - reach - margin - y0) / w->dy - 0.5), 0.0);
    j_hi = min2(ceil((y + reach + margin - y0) / w->dy - 0.5), (double)w->ny - 1.0);
    if (i_lo > i_hi || j_lo > j_hi) return limit; /* beside the stock */
    j_tool = clamp(floor_index(clamp((y - y0) / w->dy - 0.5, j_lo - 1.0, j_hi + 1.0)), j_lo, j_hi);
    for (direction = -1; direction <= 1; direction += 2) { /* |ey| grows from row to row in each direction */
        for (jd = direction < 0 ? j_tool : j_tool + 1.0; jd >= j_lo && jd <= j_hi; jd += (double)direction) {
            const double ey = y0 + (jd + 0.5) * w->dy - y;
            const double gap = fabs(ey) - r, span = r + best + margin;
            double from, to;
            if (gap > best) break; /* and the rows beyond */
            from = max2(ceil_index(clamp((x - span - x0) / w->dx - 0.5, i_lo - 1.0, i_hi + 1.0)), i_lo);
            to = min2(floor_index(clamp((x + span - x0) / w->dx - 0.5, i_lo - 1.0, i_hi + 1.0)), i_hi);
            if (from <= to)
                best = nearest_in_row(instance, instance->heap + index_of(jd) * w->nx, ey, index_of(from),
                                      index_of(to) + 1, best);
            if (best == 0.0) return 0.0;
        }
    }
    return best;
}

/* The tool's footprint (the disc of radius R about its axis) overlaps the block seen from above. */
static bool over_the_stock(const FmuInstance *instance) {
    const ModelVariables *v = &instance->v;
    const ModelInternal *w = &instance->internal;
    const double gap_x = max2(max2(v->stock_x_min - w->x, 0.0), w->x - (v->stock_x_min + v->stock_length));
    const double gap_y = max2(max2(v->stock_y_min - w->y, 0.0), w->y - (v->stock_y_min + v->stock_width));
    return gap_x * gap_x + gap_y * gap_y < w->radius * w->radius;
}

/* A tool change (model_do_step()): the new tool in the spindle from the step's start, its tip below the previous
 * controlled point by the new tool_length, the tool derived again for it, nothing reused from the old tool, the
 * shank warning re-armed (models/workpiece.py: a tool change). A tool the checks of initialization reject is an
 * error, and so is a heap that cannot grow: nothing changed then. */
static FmuStatus change_tool(FmuInstance *instance, double time) {
    ModelInternal *w = &instance->internal;
    const ModelVariables *v = &instance->v;
    char where[64];
    snprintf(where, sizeof where, "doStep: t = %g s: tool change", time);
    if (check_tool(instance, where) != FMU_OK || derive_tool(instance, "doStep") != FMU_OK) return FMU_ERROR;
    w->z = w->point_z - v->tool_length;
    forget_reuse(w);
    w->warned_shank = false;
    fmu_log(instance, FMU_OK, "logEvents",
            "%s: tool_diameter = %g m, corner_radius = %g m, tool_length = %g m (%zu angle and %zu corner samples)",
            where, v->tool_diameter, v->corner_radius, v->tool_length, w->n_angles + 1, w->n_corner + 1);
    return FMU_OK;
}

FmuStatus model_do_step(FmuInstance *instance, double time, double step_size) {
    ModelInternal *w = &instance->internal;
    const ModelVariables *v = &instance->v;
    double start[3], end[3], sx, sy, sz, travel, horizontal, volume, step_top = -INFINITY, stretch_top;
    FmuStatus status = FMU_OK;
    /* tunable parameters set since the last step (FMI: between steps): a new tool, or a new flute length */
    if (v->tool_diameter != w->tool_diameter || v->corner_radius != w->corner_radius ||
        v->tool_length != w->tool_length) {
        if (change_tool(instance, time) != FMU_OK) return FMU_ERROR;
    }
    if (v->flute_length != w->flute_length) {
        w->flute_length = v->flute_length;
        w->warned_shank = false;
    }
    start[0] = w->x;
    start[1] = w->y;
    start[2] = w->z;
    end[0] = v->tool_x;
    end[1] = v->tool_y;
    end[2] = v->tool_z - v->tool_length;
    sx = end[0] - start[0];
    sy = end[1] - start[1];
    sz = end[2] - start[2];
    travel = sqrt(sx * sx + sy * sy + sz * sz);
    horizontal = sqrt(sx * sx + sy * sy);
    if (travel > v->max_tool_speed * step_size) {
        fmu_log(instance, FMU_ERROR, "logStatusError",
                "doStep: t = %g s: the tool tip moved %g m in %g s (%g m/s), faster than max_tool_speed = %g m/s: "
                "a jump in tool_x, tool_y, tool_z (a glitch, or not in m?)", time, travel, step_size,
                travel / step_size, v->max_tool_speed);
        return FMU_ERROR;
    }
    volume = remove_material(instance, start, end, &step_top);
    stretch_top = max2(w->stretch_top, step_top);
    w->stretch_travel += travel;
    if (horizontal > FEED_DIRECTION_MIN_TRAVEL * w->delta) {
        w->feed_x = sx / horizontal;
        w->feed_y = sy / horizontal;
    }
    w->x = end[0];
    w->y = end[1];
    w->z = end[2];
    w->point_z = v->tool_z;
    /* a step that rises more than it moves sideways and lowers no cell cuts nothing (a retract: the flanks slide
     * up the walls they touch): not engaged, as without a cut top (models/workpiece.py, step 2) */
    engagement(instance, volume, sz > horizontal && volume == 0.0 ? -INFINITY
                                                                  : max2(stretch_top, w->previous_stretch_top));
    if (w->stretch_travel >= w->radius) { /* the stretch ends with this step */
        w->previous_stretch_top = stretch_top;
        w->stretch_top = -INFINITY;
        w->stretch_travel = 0.0;
    } else {
        w->stretch_top = stretch_top;
    }
    instance->v.mrr = volume * (w->dx * w->dy) / step_size;
    w->removed_height += volume;
    instance->v.removed_volume = w->removed_height * (w->dx * w->dy);
    instance->v.clearance = clearance(instance);
    if (volume > 0.0 && fabs(v->spindle_speed) < SPINDLE_STOPPED && !w->warned_spindle_stopped) {
        w->warned_spindle_stopped = true;
        fmu_log(instance, FMU_WARNING, "logStatusWarning",
                "doStep: t = %g s: material removed while spindle_speed = %g rad/s: the spindle stands still "
                "(a crash, or spindle_speed not connected? reported once)", time, v->spindle_speed);
        status = FMU_WARNING;
    }
    if (v->axial_depth > v->flute_length && !w->warned_shank) {
        w->warned_shank = true;
        fmu_log(instance, FMU_WARNING, "logStatusWarning",
                "doStep: t = %g s: axial depth of cut %g m is more than flute_length = %g m: the shank is in the "
                "material (reported once)", time, v->axial_depth, v->flute_length);
        status = FMU_WARNING;
    }
    if (w->z < v->stock_z_min && over_the_stock(instance) && !w->warned_bottom) {
        w->warned_bottom = true;
        fmu_log(instance, FMU_WARNING, "logStatusWarning",
                "doStep: t = %g s: the tool tip went to z = %g mm, below the stock bottom stock_z_min = %g mm, with "
                "the tool over the stock at x = %g mm, y = %g mm: the program plunges through the part (into the "
                "fixture?) (reported once)", time, 1e3 * w->z, 1e3 * v->stock_z_min, 1e3 * w->x, 1e3 * w->y);
        status = FMU_WARNING;
    }
    return status;
}

/* The outputs are those of the last step (written by model_do_step; 0 before the first): they do not
 * depend on inputs set since. */
void model_update_outputs(FmuInstance *instance) { (void)instance; }

void model_free_internal(FmuInstance *instance) { (void)instance; }

/* The characters of the decimal point of the process's LC_NUMERIC locale (printf writes it: "," in a
 * decimal-comma locale an importer may run in), or NULL when it is "." (the C locale's). */
static const char *locale_point(void) {
    const struct lconv *conventions = localeconv();
    const char *point = conventions ? conventions->decimal_point : NULL;
    return point && point[0] != '\0' && strcmp(point, ".") != 0 ? point : NULL;
}

/* Writes the number with %.17g (read back, the same double) and `end` after it, with a '.' for the decimal
 * point whatever the locale: `point` (locale_point()) replaced. Returns fprintf's result. */
static int write_number(FILE *f, const char *point, double value, char end) {
    char text[64];
    const int n = snprintf(text, sizeof text, "%.17g", value);
    if (n < 0 || (size_t)n >= sizeof text) return -1;
    if (point) {
        char *at = strstr(text, point);
        if (at) { /* the point's characters (one in every common locale) become one '.' */
            const size_t length = strlen(point);
            *at = '.';
            memmove(at + 1, at + length, strlen(at + length) + 1);
        }
    }
    return fprintf(f, "%s%c", text, end);
}

/* The heights as an ESRI ASCII grid (models/workpiece.py: the final Z-map) to f; false on a write error. Every
 * number has a '.' as its decimal point, in any locale. */
static bool write_grid(const FmuInstance *instance, FILE *f) {
    const ModelInternal *w = &instance->internal;
    const ModelVariables *v = &instance->v;
    const char *point = locale_point();
    size_t i, j;
    fprintf(f, "ncols %zu\nnrows %zu\nxllcorner ", w->nx, w->ny);
    write_number(f, point, v->stock_x_min, '\n');
    fprintf(f, "yllcorner ");
    write_number(f, point, v->stock_y_min, '\n');
    if (w->dx == w->dy) {
        fprintf(f, "cellsize ");
        write_number(f, point, w->dx, '\n');
    } else {
        fprintf(f, "dx ");
        write_number(f, point, w->dx, '\n');
        fprintf(f, "dy ");
        write_number(f, point, w->dy, '\n');
    }
    fprintf(f, "NODATA_value -9999\n");
    for (j = w->ny; j-- > 0;) { /* from north (largest y) to south */
        const double *row = instance->heap + j * w->nx;
        for (i = 0; i < w->nx; i++)
            if (write_number(f, point, row[i], i + 1 < w->nx ? ' ' : '\n') < 0) return false;
    }
    return !ferror(f);
}

/* Writes the final Z-map to zmap_file (if not empty): to "<zmap_file>.tmp", then renamed, so a failed write never
 * leaves a truncated file under the final name. */
FmuStatus model_terminate(FmuInstance *instance, const char *function) {
    const char *path = instance->v.zmap_file;
    char temporary[FMU_STRING_CAPACITY + 8];
    const char *failed = "write";
    FILE *f;
    int error = 0;
    if (path[0] == '\0') return FMU_OK;
    if (!instance->heap) return FMU_OK; /* not initialized: no Z-map (Terminate is only allowed after it) */
    snprintf(temporary, sizeof temporary, "%s.tmp", path);
    errno = 0;
    f = fopen(temporary, "w");
    if (!f) {
        error = errno;
        failed = "create";
    } else {
        bool written = write_grid(instance, f);
        if (!written) error = errno;
        if (fclose(f) != 0 && written) {
            written = false;
            error = errno;
        }
        if (written) {
            errno = 0;
            if (rename(temporary, path) == 0) return FMU_OK;
#ifdef _WIN32 /* rename does not replace an existing file there */
            if (remove(path) == 0 && rename(temporary, path) == 0) return FMU_OK;
#endif
            error = errno;
            failed = "rename";
        }
        remove(temporary);
    }
    if (strcmp(failed, "rename") == 0)
        fmu_log(instance, FMU_ERROR, "logStatusError", "%s: zmap_file = '%s': cannot rename '%s' to '%s': %s",
                function, path, temporary, path, error ? strerror(error) : "unknown error");
    else
        fmu_log(instance, FMU_ERROR, "logStatusError", "%s: zmap_file = '%s': cannot %s '%s': %s", function, path,
                failed, temporary, error ? strerror(error) : "unknown error");
    return FMU_ERROR;
}
