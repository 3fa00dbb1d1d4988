/* Workpiece: a Z-map of the stock block cut by a flat, bull-nose or ball end mill (models/workpiece.py
 * describes the algorithm; models.workpiece.ZMap is the same in numpy, operation for operation, and the
 * tests compare the two to the last bit). Per step: remove the material under the tool swept from the
 * previous to the current tool tip position, visiting only the cells under the swept tool, then
 * compute the engagement at the new position: depths, entry and exit angles, MRR and the map. */
#include <math.h>
#include <string.h>

#include "fmu_instance.h"

#define PI 3.14159265358979323846
#define MAX_CELLS 20000000.0             /* memory cap: 160 MB of heights (models.workpiece.MAX_CELLS) */
#define MIN_CELLS_ACROSS_TOOL 4.0
#define DESCEND_PER_SUBSEGMENT 0.25      /* times delta */
#define FEED_DIRECTION_MIN_TRAVEL 1e-3   /* times delta */
#define SPINDLE_STOPPED (2.0 * PI / 60.0) /* rad/s: 1 rpm */
#define N_BISECTIONS 10                  /* refinement of entry and exit between two angle samples */

/* the map is one row-major array of N_Z x N_THETA values (models.workpiece: shape of "engagement") */
typedef char map_size_matches_the_model[(SIZE_engagement == WORKPIECE_N_Z * WORKPIECE_N_THETA) ? 1 : -1];

static double cell_count(double size, double resolution) { return ceil(size / resolution - 1e-6); }

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

FmuStatus model_exit_initialization(FmuInstance *instance) {
    static const char *const function = "exitInitializationMode";
    const ModelVariables *v = &instance->v;
    ModelInternal *w = &instance->internal;
    double nx, ny, arc, *heap;
    size_t k, count;

    if (v->corner_radius > 0.5 * v->tool_diameter) {
        fmu_log(instance, FMU_ERROR, "logStatusError",
                "%s: corner_radius = %g m is larger than tool_diameter/2 = %g m (0: flat end mill, "
                "tool_diameter/2: ball end mill)", function, v->corner_radius, 0.5 * v->tool_diameter);
        return FMU_ERROR;
    }
    if (v->tool_diameter > v->stock_length || v->tool_diameter > v->stock_width) {
        fmu_log(instance, FMU_ERROR, "logStatusError",
                "%s: the tool is larger than the stock: tool_diameter = %g m, stock_length = %g m, stock_width = "
                "%g m", function, v->tool_diameter, v->stock_length, v->stock_width);
        return FMU_ERROR;
    }
    if (v->tool_diameter < MIN_CELLS_ACROSS_TOOL * v->resolution) {
        fmu_log(instance, FMU_ERROR, "logStatusError",
                "%s: resolution = %g m is too coarse for tool_diameter = %g m: the Z-map needs at least %g cells "
                "across the tool (resolution <= %g m)", function, v->resolution, v->tool_diameter,
                MIN_CELLS_ACROSS_TOOL, v->tool_diameter / MIN_CELLS_ACROSS_TOOL);
        return FMU_ERROR;
    }
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
    w->radius = 0.5 * v->tool_diameter;
    w->corner = v->corner_radius;
    w->flat = w->radius - w->corner;
    w->n_angles = (size_t)ceil(PI * w->radius / w->delta);
    w->n_corner = w->corner > 0.0 ? (size_t)ceil(0.5 * PI * w->corner / w->delta) : 0;
    w->cos_phi = w->nx * w->ny;
    w->sin_phi = w->cos_phi + w->n_angles + 1;
    w->profile_z = w->sin_phi + w->n_angles + 1;
    w->profile_r = w->profile_z + w->n_corner + 1;
    count = w->profile_r + w->n_corner + 1;
    if (fmu_allocate_heap(instance, function, count) != FMU_OK) return FMU_ERROR;
    heap = instance->heap;
    for (k = 0; k < w->nx * w->ny; k++) heap[k] = w->top;
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

    w->x = v->tool_x;
    w->y = v->tool_y;
    w->z = v->tool_z;
    w->feed_x = 1.0;
    w->feed_y = 0.0;
    return FMU_OK;
}

/* Lower the cells under the tool moved in a straight line from a to b; returns volume plus the sum of
 * the height drops (in cell order: the reference sums in the same order). Cells that cannot change
 * are not computed (the others exactly as the reference does, so the result is the same): those
 * of a row beyond the tool's reach (the row's cells within r of the segment lie within
 * sqrt(r^2 - dy^2) of its x extent, dy the row's distance from its y extent; one cell of margin),
 * and those already at or below the lowest the tool reaches here (the lower end of the segment) or
 * the stock's bottom. */
static double remove_segment(FmuInstance *instance, const double a[3], const double b[3], double volume) {
    const ModelInternal *w = &instance->internal;
    const double x0 = instance->v.stock_x_min, y0 = instance->v.stock_y_min, z0 = instance->v.stock_z_min;
    const double sx = b[0] - a[0], sy = b[1] - a[1], sz = b[2] - a[2];
    const double length2 = sx * sx + sy * sy, r = w->radius, r2 = r * r;
    const double flat2 = w->flat * w->flat, corner = w->corner, corner2 = corner * corner;
    const double x_min = fmin(a[0], b[0]), x_max = fmax(a[0], b[0]), y_min = fmin(a[1], b[1]), y_max = fmax(a[1], b[1]);
    /* the lowest tip height computed below: a[2] + t*sz with t in [0, 1] is at least a[2] + sz (rounding
     * is monotonic), or min(a[2], b[2]) for a vertical move; a corner only adds corner - sqrt(...) >= 0 */
    const double unreachable = fmax(fmin(fmin(a[2], b[2]), a[2] + sz), z0); /* a cell at or below: no change */
    double i_lo, i_hi, j_lo, j_hi;
    size_t i, j;
    if (fmin(a[2], b[2]) >= w->top) return volume; /* above the stock: nothing to cut */
    i_lo = fmax(floor((fmin(a[0], b[0]) - r - x0) / w->dx - 0.5), 0.0);
    i_hi = fmin(ceil((fmax(a[0], b[0]) + r - x0) / w->dx - 0.5), (double)w->nx - 1.0);
    j_lo = fmax(floor((fmin(a[1], b[1]) - r - y0) / w->dy - 0.5), 0.0);
    j_hi = fmin(ceil((fmax(a[1], b[1]) + r - y0) / w->dy - 0.5), (double)w->ny - 1.0);
    if (i_lo > i_hi || j_lo > j_hi) return volume; /* beside the stock */
    for (j = (size_t)j_lo; j <= (size_t)j_hi; j++) {
        const double cy = y0 + ((double)j + 0.5) * w->dy;
        const double dy = cy < y_min ? y_min - cy : (cy > y_max ? cy - y_max : 0.0);
        const double reach = sqrt(fmax(r2 - dy * dy, 0.0)) + w->dx;
        const double row_lo = fmax(floor((x_min - reach - x0) / w->dx - 0.5), i_lo);
        const double row_hi = fmin(ceil((x_max + reach - x0) / w->dx - 0.5), i_hi);
        double *row = instance->heap + j * w->nx;
        if (dy > r + w->dy || row_lo > row_hi) continue;
        for (i = (size_t)row_lo; i <= (size_t)row_hi; i++) {
            const double cx = x0 + ((double)i + 0.5) * w->dx;
            double qx, qy, zt, ex, ey, d2, zc;
            if (row[i] <= unreachable) continue;
            if (length2 > 0.0) { /* the point of the segment closest to the cell centre */
                double t = ((cx - a[0]) * sx + (cy - a[1]) * sy) / length2;
                if (t < 0.0)
                    t = 0.0;
                else if (t > 1.0)
                    t = 1.0;
                qx = a[0] + t * sx;
                qy = a[1] + t * sy;
                zt = a[2] + t * sz;
            } else { /* a vertical move: the lowest position */
                qx = a[0];
                qy = a[1];
                zt = fmin(a[2], b[2]);
            }
            ex = cx - qx;
            ey = cy - qy;
            d2 = ex * ex + ey * ey;
            if (d2 > r2) continue;
            zc = zt;
            if (corner > 0.0 && d2 > flat2) {
                const double e = sqrt(d2) - w->flat;
                zc = zt + (corner - sqrt(fmax(corner2 - e * e, 0.0)));
            }
            if (zc < z0) zc = z0;
            if (zc < row[i]) {
                volume += row[i] - zc;
                row[i] = zc;
            }
        }
    }
    return volume;
}

/* The move of one step, in sub-segments that descend at most DESCEND_PER_SUBSEGMENT * delta each
 * (one for a move without horizontal travel). Returns the sum of the height drops. */
static double remove_material(FmuInstance *instance, const double start[3], const double end[3]) {
    const double sx = end[0] - start[0], sy = end[1] - start[1], sz = end[2] - start[2];
    double volume = 0.0, a[3], b[3], n = 1.0, k;
    if (sx * sx + sy * sy > 0.0)
        n = fmax(1.0, ceil(fabs(sz) / (DESCEND_PER_SUBSEGMENT * instance->internal.delta)));
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
        volume = remove_segment(instance, a, b, volume);
        memcpy(a, b, sizeof a);
    }
    return volume;
}

/* Stock height at (px, py) minus z; -inf outside the block. */
static double height_above(const FmuInstance *instance, double px, double py, double z) {
    const ModelInternal *w = &instance->internal;
    const double fi = floor((px - instance->v.stock_x_min) / w->dx);
    const double fj = floor((py - instance->v.stock_y_min) / w->dy);
    if (!(fi >= 0.0 && fi < (double)w->nx && fj >= 0.0 && fj < (double)w->ny)) return -INFINITY;
    return instance->heap[(size_t)fj * w->nx + (size_t)fi] - z;
}

/* Any profile sample at angle phi in material (the test of the scan in engagement(), at one angle). */
static bool engaged_at(const FmuInstance *instance, double phi) {
    const ModelInternal *w = &instance->internal;
    const double *heap = instance->heap;
    const double c = cos(phi), s = sin(phi);
    const double ux = s * w->feed_x - c * w->feed_y, uy = s * w->feed_y + c * w->feed_x;
    size_t k;
    for (k = 0; k <= w->n_corner; k++) {
        const double rho = heap[w->profile_r + k] + w->delta;
        if (height_above(instance, w->x + rho * ux, w->y + rho * uy, w->z) > heap[w->profile_z + k]) return true;
    }
    return false;
}

/* The engaged angle next to the boundary between the samples `inside` (engaged) and `outside`. */
static double boundary(const FmuInstance *instance, double inside, double outside) {
    int n;
    for (n = 0; n < N_BISECTIONS; n++) {
        const double middle = 0.5 * (inside + outside);
        if (engaged_at(instance, middle))
            inside = middle;
        else
            outside = middle;
    }
    return inside;
}

/* Outputs at the current tool position against the current stock (all 0 when not engaged). */
static void engagement(FmuInstance *instance) {
    const ModelInternal *w = &instance->internal;
    const double *heap = instance->heap;
    const double x = w->x, y = w->y, z = w->z, fx = w->feed_x, fy = w->feed_y;
    const double column = 2.0 * PI / WORKPIECE_N_THETA;
    double axial = -INFINITY, entry, leave, r_top, widen, cos_entry, cos_exit;
    double column_ux[WORKPIECE_N_THETA], column_uy[WORKPIECE_N_THETA];
    size_t m, k, first = 0, last = 0, n_columns = 0;
    int i, j, columns[WORKPIECE_N_THETA];
    bool engaged = false;
    for (i = 0; i < WORKPIECE_N_Z * WORKPIECE_N_THETA; i++) instance->v.engagement[i] = 0.0;
    instance->v.axial_depth = instance->v.radial_depth = instance->v.entry_angle = instance->v.exit_angle = 0.0;
    if (z >= w->top) return;
    m = 0;
    while (m <= w->n_angles) { /* runs of consecutive engaged samples */
        const size_t start = m;
        double run_top = -INFINITY;
        bool run_cutting = false;
        for (; m <= w->n_angles; m++) {
            const double c = heap[w->cos_phi + m], s = heap[w->sin_phi + m];
            const double ux = s * fx - c * fy, uy = s * fy + c * fx;
            double best = -INFINITY;
            bool cutting = false;
            for (k = 0; k <= w->n_corner; k++) {
                const double rho = heap[w->profile_r + k] + w->delta;
                const double above = height_above(instance, x + rho * ux, y + rho * uy, z);
                if (above > heap[w->profile_z + k]) {
                    const double top = k < w->n_corner ? fmin(above, heap[w->profile_z + k + 1]) : above;
                    if (top > best) best = top;
                    /* a test point beside the cutter's circle (within half a cell diagonal of its
                     * radius, or beyond) only touches a wall: runs of such samples are no cut */
                    if (fabs(rho * c) < heap[w->profile_r + k] - w->half_diagonal) cutting = true;
                }
            }
            if (best == -INFINITY) break;
            if (best > run_top) run_top = best;
            run_cutting = run_cutting || cutting;
        }
        if (m == start) { /* not engaged */
            m++;
            continue;
        }
        if (run_cutting) {
            if (!engaged) first = start;
            engaged = true;
            last = m - 1;
            if (run_top > axial) axial = run_top;
        }
    }
    if (!engaged) return;
    entry = angle(w, first);
    leave = angle(w, last);
    if (first > 0) entry = boundary(instance, entry, angle(w, first - 1));
    if (last < w->n_angles) leave = boundary(instance, leave, angle(w, last + 1));
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
    for (j = 0; j < WORKPIECE_N_THETA && ((double)j + 0.5) * column < PI; j++) {
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
    for (i = 0; i < WORKPIECE_N_Z; i++) {
        const double zi = ((double)i + 0.5) * (axial / WORKPIECE_N_Z);
        const double ri = radius_at(w, zi) + w->delta;
        for (k = 0; k < n_columns; k++) {
            if (height_above(instance, x + ri * column_ux[k], y + ri * column_uy[k], z) > zi)
                instance->v.engagement[i * WORKPIECE_N_THETA + columns[k]] = 1.0;
        }
    }
}

FmuStatus model_do_step(FmuInstance *instance, double time, double step_size) {
    ModelInternal *w = &instance->internal;
    const ModelVariables *v = &instance->v;
    const double start[3] = {w->x, w->y, w->z}, end[3] = {v->tool_x, v->tool_y, v->tool_z};
    const double sx = end[0] - start[0], sy = end[1] - start[1], sz = end[2] - start[2];
    const double travel = sqrt(sx * sx + sy * sy + sz * sz), horizontal = sqrt(sx * sx + sy * sy);
    double volume;
    FmuStatus status = FMU_OK;
    if (travel > v->max_tool_speed * step_size) {
        fmu_log(instance, FMU_ERROR, "logStatusError",
                "doStep: t = %g s: the tool tip moved %g m in %g s (%g m/s), faster than max_tool_speed = %g m/s: "
                "a jump in tool_x, tool_y, tool_z (a glitch, or not in m?)", time, travel, step_size,
                travel / step_size, v->max_tool_speed);
        return FMU_ERROR;
    }
    volume = remove_material(instance, start, end);
    if (horizontal > FEED_DIRECTION_MIN_TRAVEL * w->delta) {
        w->feed_x = sx / horizontal;
        w->feed_y = sy / horizontal;
    }
    w->x = end[0];
    w->y = end[1];
    w->z = end[2];
    engagement(instance);
    instance->v.mrr = volume * (w->dx * w->dy) / step_size;
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
    return status;
}

/* The outputs are those of the last step (written by model_do_step; 0 before the first): they do not
 * depend on inputs set since. */
void model_update_outputs(FmuInstance *instance) { (void)instance; }

void model_free_internal(FmuInstance *instance) { (void)instance; }
