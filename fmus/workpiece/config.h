/* Workpiece: variables are generated from models/workpiece.py (model_generated.h); all outputs are
 * computed by model.c (the Z-map cannot be expressed in casadi). The reference implementation of the
 * same algorithm is models.workpiece.ZMap; tests/test_workpiece.py proves the two equal.
 *
 * The instance heap (fmu_allocate_heap, copied into FMU states) holds, in doubles:
 *   heights   [nx * ny]      stock height above each cell centre, row-major (index j * nx + i)
 *   cos_phi   [n_angles + 1] cos/sin of the angle samples m * pi / n_angles of the front half
 *   sin_phi   [n_angles + 1]
 *   profile_z [n_corner + 1] height above the tip and radius of the profile samples: along the
 *   profile_r [n_corner + 1] corner arc, the last one the cylinder (corner_radius, R)
 * The tables follow the heights: at a tool change they are derived again, the heap resized, the heights kept. */
#ifndef CONFIG_H
#define CONFIG_H

#include "model_generated.h"
#include "model_constants.h" /* N_Z x N_THETA (the engagement map), N_BISECTIONS, the grid limits: models/workpiece.py */

#define MODEL_HAS_TERMINATE 1 /* fmu_instance.h: model_terminate writes the final Z-map to zmap_file */

/* Where a set of probes of the stock was made (the tool at x, y) and how far the probes then lay from
 * the edges of their cells, in cells, towards -x, +x, -y, +y: the set gives the same heights while the
 * tool moves less (model.c: rooms_hold()). */
typedef struct {
    bool valid;
    double x, y;
    double x_minus, x_plus, y_minus, y_plus;
} ProbeRooms;

typedef struct {
    /* the grid, fixed at initialization */
    size_t nx, ny;
    double dx, dy;          /* cell size [m] */
    double delta;           /* min(dx, dy): offset of the engagement test outside the cutting circle [m] */
    double half_diagonal;   /* of a cell: how far a point may lie from the centre of its cell [m] */
    double arc_margin;      /* half_diagonal + 2 delta (1 + delta / 2R): how far inside the cutter's radius the
                             * test circle meets a wall an earlier level left along an arc of path radius R/2;
                             * the engaged height comes from points farther in (model.c: scan()) [m] */
    double top;             /* top of the stock block [m] */
    /* the tool, derived at initialization and again at a tool change (model.c: derive_tool()) */
    double tool_diameter, corner_radius, tool_length; /* the parameters it was derived from: others at a doStep
                                                       * are a tool change */
    double flute_length;    /* the value the shank warning was armed for */
    double radius, corner, flat; /* tool radius, corner radius, radius of the flat bottom [m] */
    size_t n_angles, n_corner;
    size_t cos_phi, sin_phi, profile_z, profile_r; /* offsets of the tables in the heap */
    /* kept between steps */
    double x, y, z;         /* tool tip at the end of the last step [m] */
    double point_z;         /* the controlled point's z (tool_z) then: z + tool_length up to rounding [m] */
    double feed_x, feed_y;  /* unit vector of the last horizontal move (+x before the first) */
    double removed_height;  /* the sum of all height drops so far [m]: removed_volume / (dx dy) */
    /* The cut top (models/workpiece.py, step 2): the highest height before the cut of the cells lowered in the
     * current stretch of travel and in the previous one (-inf: none), and the current stretch's travel [m] */
    double stretch_top, previous_stretch_top, stretch_travel;
    bool warned_spindle_stopped;
    bool warned_shank;
    bool warned_bottom;     /* the tool tip below the stock bottom over the stock */
    /* Every cell whose centre lies within radius - 2 delta/16 of (cleared_x, cleared_y) is at or below
     * cleared_level (model.c: remove_segment(); heights only decrease, so it stays true) */
    bool cleared_valid;
    double cleared_x, cleared_y, cleared_level;
    /* Reuse between steps (model.c: engagement()), exact: all part of FMU states. The key: z and the feed of
     * the last engagement, and no cell lowered since. */
    double probed_z, probed_feed_x, probed_feed_y;
    ProbeRooms scan_rooms;  /* probes of the angle scan, whose result follows */
    size_t scan_first, scan_last;
    double scan_axial;
    bool scan_engaged;
    ProbeRooms bisection_rooms; /* probes of the bisections from these samples, whose result follows */
    size_t bisected_first, bisected_last;
    double bisected_entry, bisected_leave;
    ProbeRooms map_rooms;   /* probes of the map; outputs valid for the refined angles and depth below */
    double outputs_entry, outputs_leave, outputs_axial;
    /* the angles of the last bisections (entry, exit) and their cos and sin */
    double bisection_phi[2][N_BISECTIONS], bisection_cos[2][N_BISECTIONS],
        bisection_sin[2][N_BISECTIONS];
} ModelInternal;

#endif
