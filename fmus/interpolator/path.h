/* The path as the feedrate schedule sees it: moves laid end to end along the arc length s, nodes along s
 * with their hard speed caps (chord error, centripetal acceleration, curvature jerk, axis shares,
 * junctions), intervals with their tangential limits. Mirrored by models/interpolator/path.py. */
#ifndef PATH_H
#define PATH_H

#include <stddef.h>

#include "gcode_parser.h"


typedef struct {
    double period, acceleration, jerk, centripetal, chord;
    double axis_acceleration[3], axis_jerk[3];
    double max_feed; /* the highest path speed (max of max_feed and rapid_feed): bounds a step's length */
} Limits;

typedef struct {
    double center[3], end[3];
    int axes[3];
    double theta0, sweep, r0, r1, height;
} ArcParams;

typedef struct {
    size_t n_moves;
    double *move_s, *move_length, *move_cap;
    int *span_lo, *span_hi;
    size_t n_curves;
    double **pw; /* homogeneous control points of each curve, 4 per point */
    size_t n_nodes, n_ints;
    double *node_s, *node_vh;
    int *node_left, *node_right;
    unsigned char *station;
    int *int_move;
    double *int_at, *int_jt, *int_cap;
    double total;
} PathBuild;

/* Refusals (a zero tangent, too many samples) in the parser's format, quoting the line of `text`. */
int path_build(const GcProgram *program, const Limits *limits, const char *text, size_t text_length, const char *file,
               PathBuild *out, char *error, size_t error_size);
void path_free(PathBuild *path);

void tangential_limits(const Limits *lim, const double t[3], int curved, double *at, double *jt);
double curvature_limit(const Limits *lim, double kappa, const double k[3], const double kp[3], double at);
/* The tangential acceleration limit lowered so that the coupling 3 v a |k_i| stays within what each axis's jerk leaves
 * over |t_i| jt and v^3 |k'_i| at the speed limit v (near a cusp the acceleration, not the speed, gives way). */
double coupled_acceleration(const Limits *lim, const double t[3], double jt, const double k[3], const double kp[3],
                            double v, double at);
double junction_limit(const Limits *lim, const double ta[3], const double ka[3], const double tb[3],
                      const double kb[3]);

void arc_params(const GcMove *m, ArcParams *a);
double arc_length(const ArcParams *a);
void arc_point(const ArcParams *a, double lam, double p[3]);
void arc_tangent(const ArcParams *a, double lam, double t[3]);

#endif
