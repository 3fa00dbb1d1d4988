/* NURBS parameter update: u(i+1) for a scheduled step length, by first- or second-order Taylor expansion,
 * the RBF-network predictor, or a predictor refined by Newton iterations on the arc length of the step. Mirrored by
 * models/interpolator/param_update.py. */
#ifndef PARAM_UPDATE_H
#define PARAM_UPDATE_H

#include "nurbs.h"

/* METHOD_TAYLOR1..METHOD_CORRECTOR, RBF_HIDDEN, RBF_INPUTS, MAX_NEWTON: model_constants.h (through nurbs.h) */

typedef struct {
    double width;
    double offset[RBF_INPUTS], scale[RBF_INPUTS];
    double centers[RBF_HIDDEN][RBF_INPUTS];
    double weights[RBF_HIDDEN];
    double bias;
} RbfParams;

/* The state of the NURBS move being traversed (flat: part of the FMU state). */
typedef struct {
    int move;              /* index of the move, -1 none */
    int count;             /* points computed in this move */
    double u, u1, u2;      /* u(i), u(i-1), u(i-2) */
    double s_done;         /* scheduled length done in this move */
    double s_actual;       /* arc length travelled in this move (each chord's arc) */
    double point[3], d1[3], d2[3]; /* C, C', C'' at u */
    double upp_prev;       /* d2u/ds2 at u(i-1) */
    double chord_prev;     /* |C(u(i)) - C(u(i-1))| */
} NurbsState;

typedef struct {
    int method;    /* METHOD_* */
    int predictor; /* for METHOD_CORRECTOR: METHOD_TAYLOR1..METHOD_RBF */
    int feedback;  /* steps aim at the scheduled length from the chords travelled (arc_length_feedback) */
    double tolerance;
    RbfParams rbf;
} UpdateSettings;

double rbf_output(const RbfParams *net, const double raw[RBF_INPUTS]);
/* kappa^2 from the u-derivatives C' = d1, C'' = d2 (0 where rounding makes it negative). */
double curvature_squared(const double d1[3], const double d2[3]);
/* The arc over a chord between points of curvature squared k2a, k2b: chord + (k2a + k2b) / 2 chord^3 / 24. */
double arc_of_chord(double chord, double k2a, double k2b);
/* The predicted parameter step for a step length, before any correction. */
double predict_step(const NurbsState *st, double length, int predictor, const RbfParams *net, double ua, double ub);
/* Starts a move at u0: point and derivatives there. */
void nurbs_state_start(NurbsState *st, int move, const NurbsView *curve, double u0, int lo, int hi);
/* Moves to u (evaluated in d: C, C', C''), as the next point, `chord` from the last one and `arc` along the curve. */
void nurbs_state_accept(NurbsState *st, double u, const double d[3][3], double upp_prev, double chord, double arc);
/* One scheduled step of length `step` along the move [u0, u1] (spans lo..hi). */
void nurbs_state_advance(NurbsState *st, const NurbsView *curve, double u0, double u1, int lo, int hi, double step,
                         const UpdateSettings *settings);

#endif
