/* Workpiece: variables are generated from models/workpiece.py (model_generated.h); all outputs are
 * computed by model.c (the Z-map cannot be expressed in casadi). The reference implementation of the
 * same algorithm is models.workpiece.ZMap; tests/test_workpiece.py proves the two equal.
 *
 * The instance heap (fmu_allocate_heap, copied into FMU states) holds, in doubles:
 *   heights   [nx * ny]      stock height above each cell centre, row-major (index j * nx + i)
 *   cos_phi   [n_angles + 1] cos/sin of the angle samples m * pi / n_angles of the front half
 *   sin_phi   [n_angles + 1]
 *   profile_z [n_corner + 1] height above the tip and radius of the profile samples: along the
 *   profile_r [n_corner + 1] corner arc, the last one the cylinder (corner_radius, R) */
#ifndef CONFIG_H
#define CONFIG_H

#include "model_generated.h"

#define WORKPIECE_N_Z 8       /* rows of the engagement map: models.workpiece.N_Z */
#define WORKPIECE_N_THETA 24  /* columns of the engagement map: models.workpiece.N_THETA */

typedef struct {
    /* the grid and the tool, fixed at initialization */
    size_t nx, ny;
    double dx, dy;          /* cell size [m] */
    double delta;           /* min(dx, dy): offset of the engagement test outside the cutting circle [m] */
    double half_diagonal;   /* of a cell: how far a point may lie from the centre of its cell [m] */
    double top;             /* top of the stock block [m] */
    double radius, corner, flat; /* tool radius, corner radius, radius of the flat bottom [m] */
    size_t n_angles, n_corner;
    size_t cos_phi, sin_phi, profile_z, profile_r; /* offsets of the tables in the heap */
    /* kept between steps */
    double x, y, z;         /* tool tip at the end of the last step [m] */
    double feed_x, feed_y;  /* unit vector of the last horizontal move (+x before the first) */
    bool warned_spindle_stopped;
    bool warned_shank;
} ModelInternal;

#endif
