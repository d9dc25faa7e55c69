// test_trajectory.c: keyframe trajectories (sd_trajectory.h) against their defining properties
// (interpolation, rest at both ends, C2 continuity, derivatives that are derivatives) and against
// independent routes to the same numbers: closed forms for two and three keyframes, a cubic the
// spline must reproduce, a cubic spline computed here from its second derivatives by a dense
// Gaussian elimination in double, and the quintic Hermite polynomial solved from its six
// conditions.
#include <float.h>
#include <math.h>
#include <string.h>

#include "fixtures.h"
#include "harness.h"
#include "sd_trajectory.h"

// Tolerances are relative to the natural scales of a dof: Q = max |knot_q| for positions,
// Q / hmin for velocities and Q / hmin^2 for accelerations (hmin the smallest keyframe gap).
#ifdef SD_SINGLE
#define TR_REL 1e-4        // float data and math against double: measured up to 2.6e-5
#define TR_DELTA 1e-3      // one-sided offsets at a keyframe, times hmin: well above a time ulp
#define TR_FD_STEP 3e-3    // central-difference step, times the segment length
#define TR_TOL_FD 1e-3     // central differences: step^2 truncation plus rounding / step
#define TR_HUGE (FLT_MAX / 4)
#define TR_TINY 1e-25      // a gap whose square underflows to 0
#else
#define TR_REL 1e-12       // measured up to 3e-14
#define TR_DELTA 1e-9
#define TR_FD_STEP 1e-5
#define TR_TOL_FD 1e-8
#define TR_HUGE (DBL_MAX / 4)
#define TR_TINY 1e-200
#endif

static sd_trajectory g_tr;

//---------------------------------- helpers ------------------------------------------------------

// random keyframes: start at 0.5 s, gaps in [0.2, 1] s (neighbours differ up to 5x), dof j of
// amplitude 1, 0.02 or 40 (j mod 3) so that errors are judged relative to each dof's own scale
static void fill_random(sd_trajectory* tr, int nknot, int ndof, unsigned seed) {
  static const double amp[3] = {1.0, 0.02, 40.0};
  tr->nknot = nknot;
  tr->ndof = ndof;
  double t = 0.5;
  for (int k = 0; k < nknot; k++) {
    tr->knot_t[k] = (sd_real)t;
    t += sdt_uniform(&seed, 0.2, 1.0);
    for (int j = 0; j < ndof; j++) {
      tr->knot_q[k][j] = (sd_real)(amp[j % 3] * sdt_uniform(&seed, -1.5, 1.5));
    }
  }
}

static double knot_time(const sd_trajectory* tr, int k) {
  return (double)tr->knot_t[k];
}

static double min_gap(const sd_trajectory* tr) {
  double h = INFINITY;
  for (int k = 1; k < tr->nknot; k++) h = fmin(h, knot_time(tr, k) - knot_time(tr, k - 1));
  return h;
}

// Q of dof j: the largest |knot_q| (at least 1e-30)
static double dof_scale(const sd_trajectory* tr, int j) {
  double s = 1e-30;
  for (int k = 0; k < tr->nknot; k++) s = fmax(s, fabs((double)tr->knot_q[k][j]));
  return s;
}

// the scales of q, qd and qdd of dof j
static void dof_scales(const sd_trajectory* tr, int j, double scale[3]) {
  double h = min_gap(tr);
  scale[0] = dof_scale(tr, j);
  scale[1] = scale[0] / h;
  scale[2] = scale[0] / (h * h);
}

// evaluate at t rounded to sd_real; out[j][0..2] = q, qd, qdd of dof j; returns the time used
static double eval_at(const sd_trajectory* tr, double t, double out[][3]) {
  sd_real q[SD_MAX_DOF], qd[SD_MAX_DOF], qdd[SD_MAX_DOF];
  sd_real tr_t = (sd_real)t;
  sd_trajectory_eval(tr, tr_t, q, qd, qdd);
  for (int j = 0; j < tr->ndof; j++) {
    out[j][0] = (double)q[j];
    out[j][1] = (double)qd[j];
    out[j][2] = (double)qdd[j];
  }
  return (double)tr_t;
}

// keep the worst relative error; NaN sticks
static void worst_update(double* worst, double err) {
  if (err > *worst || err != err) *worst = err;
}

// solve A x = b (A n x n row-major, destroyed; x returned in b) by Gaussian elimination with
// partial pivoting; returns 0, or -1 on a zero pivot
static int dense_solve(double* A, double* b, int n) {
  for (int c = 0; c < n; c++) {
    int p = c;
    for (int r = c + 1; r < n; r++) {
      if (fabs(A[r*n + c]) > fabs(A[p*n + c])) p = r;
    }
    if (A[p*n + c] == 0) return -1;
    if (p != c) {
      for (int k = 0; k < n; k++) {
        double x = A[c*n + k]; A[c*n + k] = A[p*n + k]; A[p*n + k] = x;
      }
      double x = b[c]; b[c] = b[p]; b[p] = x;
    }
    for (int r = c + 1; r < n; r++) {
      double f = A[r*n + c] / A[c*n + c];
      for (int k = c; k < n; k++) A[r*n + k] -= f * A[c*n + k];
      b[r] -= f * b[c];
    }
  }
  for (int r = n - 1; r >= 0; r--) {
    double x = b[r];
    for (int k = r + 1; k < n; k++) x -= A[r*n + k] * b[k];
    b[r] = x / A[r*n + r];
  }
  return 0;
}

//---------------------------------- reference cubic spline ---------------------------------------

// The clamped cubic spline (zero end slopes) of one dof from its second derivatives M at the
// keyframes (the textbook "moment" equations), a different route from the core's slope
// equations and Thomas algorithm.
typedef struct ref_spline_ {
  int n;
  double t[SD_MAX_KNOT], q[SD_MAX_KNOT], M[SD_MAX_KNOT];
} ref_spline;

static double g_dense[SD_MAX_KNOT * SD_MAX_KNOT];

static int ref_spline_build(ref_spline* r, const sd_trajectory* tr, int j) {
  int n = r->n = tr->nknot;
  for (int k = 0; k < n; k++) {
    r->t[k] = knot_time(tr, k);
    r->q[k] = (double)tr->knot_q[k][j];
  }
  memset(g_dense, 0, sizeof g_dense);
  double* A = g_dense;
  for (int i = 0; i < n; i++) {
    double hl = i > 0 ? r->t[i] - r->t[i-1] : 0, hr = i < n - 1 ? r->t[i+1] - r->t[i] : 0;
    double sl = i > 0 ? (r->q[i] - r->q[i-1]) / hl : 0;    // slope 0 outside: clamped ends
    double sr = i < n - 1 ? (r->q[i+1] - r->q[i]) / hr : 0;
    if (i > 0) A[i*n + i - 1] = hl;
    A[i*n + i] = 2 * (hl + hr);
    if (i < n - 1) A[i*n + i + 1] = hr;
    r->M[i] = 6 * (sr - sl);
  }
  return dense_solve(A, r->M, n);
}

// S, S', S'' at t on segment i
static void ref_spline_eval(const ref_spline* r, int i, double t, double y[3]) {
  double h = r->t[i+1] - r->t[i], a = t - r->t[i], b = r->t[i+1] - t;
  double M0 = r->M[i], M1 = r->M[i+1];
  double c0 = r->q[i] / h - M0 * h / 6, c1 = r->q[i+1] / h - M1 * h / 6;
  y[0] = M0 * b*b*b / (6*h) + M1 * a*a*a / (6*h) + c0 * b + c1 * a;
  y[1] = -M0 * b*b / (2*h) + M1 * a*a / (2*h) - c0 + c1;
  y[2] = M0 * b / h + M1 * a / h;
}

// S' at keyframe k
static double ref_spline_slope(const ref_spline* r, int k) {
  double y[3];
  int i = k < r->n - 1 ? k : k - 1;
  ref_spline_eval(r, i, r->t[k], y);
  return y[1];
}

//---------------------------------- reference quintic --------------------------------------------

// the quintic c0 + c1 tau + ... + c5 tau^5 with value, slope and second derivative y0 at tau = 0
// and y1 at tau = h, from its six conditions by a dense solve
static int ref_quintic(double c[6], double h, const double y0[3], const double y1[3]) {
  double A[36] = {0};
  for (int k = 0; k < 6; k++) {
    A[0*6 + k] = k == 0;
    A[1*6 + k] = k == 1;
    A[2*6 + k] = k == 2 ? 2 : 0;
    A[3*6 + k] = pow(h, k);
    A[4*6 + k] = k >= 1 ? k * pow(h, k - 1) : 0;
    A[5*6 + k] = k >= 2 ? k * (k - 1) * pow(h, k - 2) : 0;
  }
  c[0] = y0[0]; c[1] = y0[1]; c[2] = y0[2];
  c[3] = y1[0]; c[4] = y1[1]; c[5] = y1[2];
  return dense_solve(A, c, 6);
}

static void quintic_eval(const double c[6], double tau, double y[3]) {
  y[0] = y[1] = y[2] = 0;
  for (int k = 5; k >= 0; k--) {
    y[0] = y[0] * tau + c[k];
    if (k >= 1) y[1] = y[1] * tau + k * c[k];
    if (k >= 2) y[2] = y[2] * tau + k * (k - 1) * c[k];
  }
}

// worst relative error of the first or last segment of dof j against the quintic Hermite
// polynomial with (q, v, a) given at its keyframes, sampled at 7 points; err[0..2] q, qd, qdd
// (a singular 6x6 system, which cannot happen for h > 0, makes the errors NaN)
static void end_segment_error(const sd_trajectory* tr, int j, int seg, const double y0[3],
                              const double y1[3], double err[3]) {
  static double out[SD_MAX_DOF][3];
  double c[6], scale[3];
  double t0 = knot_time(tr, seg), h = knot_time(tr, seg + 1) - t0;
  if (ref_quintic(c, h, y0, y1) != 0) {
    for (int d = 0; d < 3; d++) err[d] = NAN;
    return;
  }
  dof_scales(tr, j, scale);
  for (int m = 0; m <= 6; m++) {
    double t = eval_at(tr, t0 + h * (0.02 + 0.96 * m / 6), out), y[3];
    quintic_eval(c, t - t0, y);
    for (int d = 0; d < 3; d++) worst_update(&err[d], fabs(out[j][d] - y[d]) / scale[d]);
  }
}

// set a test trajectory up; a rejection is a failed check (the test then stops)
static int setup_ok(sd_trajectory* tr) {
  return EXPECT_INT(sd_trajectory_setup(tr, NULL, NULL), SD_OK,
                    "the test trajectory is valid and must be accepted");
}

//---------------------------------- validation ---------------------------------------------------

static void accepts_valid_trajectories(void) {
  int bad_knot = -99, bad_dof = -99;
  fill_random(&g_tr, 9, 3, 101);
  EXPECT_INT(sd_trajectory_setup(&g_tr, &bad_knot, &bad_dof), SD_OK,
             "9 keyframes at increasing times with finite positions are valid");
  EXPECT_INT(bad_knot, -1, "no offending keyframe in a valid trajectory");
  EXPECT_INT(bad_dof, -1, "no offending dof in a valid trajectory");
  fill_random(&g_tr, 2, 1, 102);
  EXPECT_INT(sd_trajectory_setup(&g_tr, NULL, NULL), SD_OK,
             "two keyframes and one dof are the smallest trajectory (NULL out params allowed)");
  fill_random(&g_tr, SD_MAX_KNOT, SD_MAX_DOF, 103);
  EXPECT_INT(sd_trajectory_setup(&g_tr, NULL, NULL), SD_OK,
             "SD_MAX_KNOT keyframes of SD_MAX_DOF dofs are the largest trajectory");
  EXPECT_INT(strcmp(sd_trajectory_strerror(SD_OK), "ok"), 0, "code 0 reads ok");
}

// fill a valid trajectory in, let the caller break it, and expect setup to reject it
#define REJECT(mutation, code, knot, dof, reason)                                               \
  do {                                                                                          \
    fill_random(&g_tr, 6, 3, 104);                                                              \
    mutation;                                                                                   \
    int bad_knot_ = -99, bad_dof_ = -99;                                                        \
    int got_ = sd_trajectory_setup(&g_tr, &bad_knot_, &bad_dof_);                               \
    sdt_context("%s", #mutation);                                                               \
    EXPECT_INT(got_, code, reason);                                                             \
    EXPECT_INT(bad_knot_, knot, "bad_knot must name the offending keyframe, -1 if none");       \
    EXPECT_INT(bad_dof_, dof, "bad_dof must name the offending dof, -1 if none");               \
  } while (0)

// keyframes 0.1 s apart swinging between -+TR_HUGE in dof 1: the slopes overflow
static void huge_swing(sd_trajectory* tr) {
  for (int k = 0; k < tr->nknot; k++) {
    tr->knot_t[k] = SD_R(0.1) * (sd_real)k;
    tr->knot_q[k][1] = (k % 2) ? (sd_real)TR_HUGE : -(sd_real)TR_HUGE;
  }
}

static void rejects_bad_input(void) {
  REJECT(g_tr.nknot = 1, SD_ERR_KNOTS, -1, -1, "one keyframe is no trajectory");
  REJECT(g_tr.nknot = 0, SD_ERR_KNOTS, -1, -1, "zero keyframes is no trajectory");
  REJECT(g_tr.nknot = -3, SD_ERR_KNOTS, -1, -1, "a negative keyframe count is a size error");
  REJECT(g_tr.nknot = SD_MAX_KNOT + 1, SD_ERR_KNOTS, -1, -1, "nknot must fit SD_MAX_KNOT");
  REJECT(g_tr.ndof = 0, SD_ERR_KNOTS, -1, -1, "a keyframe needs at least one dof");
  REJECT(g_tr.ndof = SD_MAX_DOF + 1, SD_ERR_KNOTS, -1, -1, "ndof must fit SD_MAX_DOF");
  REJECT(g_tr.knot_t[3] = g_tr.knot_t[2], SD_ERR_TIME, 3, -1,
         "two keyframes at the same time: times must strictly increase");
  REJECT(g_tr.knot_t[4] = g_tr.knot_t[3] - SD_R(0.1), SD_ERR_TIME, 4, -1,
         "a keyframe before the previous one: times must strictly increase");
  REJECT(g_tr.knot_t[0] = g_tr.knot_t[1] + SD_R(1.0), SD_ERR_TIME, 1, -1,
         "a first keyframe after the second: the second is the offending one");
  REJECT(g_tr.knot_t[2] = (sd_real)NAN, SD_ERR_TIME, 2, -1, "a NaN time");
  REJECT(g_tr.knot_t[5] = (sd_real)INFINITY, SD_ERR_TIME, 5, -1, "an infinite time");
  REJECT(g_tr.knot_t[0] = -(sd_real)INFINITY, SD_ERR_TIME, 0, -1, "a time of -infinity");
  REJECT((g_tr.knot_t[0] = SD_R(0.0), g_tr.knot_t[1] = (sd_real)TR_TINY), SD_ERR_TIME, 1, -1,
         "a gap whose square underflows: the accelerations would divide by zero");
  REJECT(g_tr.knot_q[2][1] = (sd_real)NAN, SD_ERR_KNOTVALUE, 2, 1, "a NaN position");
  REJECT(g_tr.knot_q[5][0] = -(sd_real)INFINITY, SD_ERR_KNOTVALUE, 5, 0, "an infinite position");
  REJECT(huge_swing(&g_tr), SD_ERR_SPLINE, 1, 1,
         "positions near the sd_real limit 0.1 s apart: the knot velocities overflow");
  sdt_context("%s", "");

  // every code has its own message
  const int codes[] = {SD_ERR_KNOTS, SD_ERR_TIME, SD_ERR_KNOTVALUE, SD_ERR_SPLINE};
  for (int a = 0; a < 4; a++) {
    sdt_context("code %d: %s", codes[a], sd_trajectory_strerror(codes[a]));
    EXPECT_INT(strcmp(sd_trajectory_strerror(codes[a]), "unknown error") != 0, 1,
               "a trajectory error code has a message");
    for (int b = 0; b < a; b++) {
      EXPECT_INT(strcmp(sd_trajectory_strerror(codes[a]), sd_trajectory_strerror(codes[b])) != 0,
                 1, "two codes, two messages");
    }
  }
  sdt_context("%s", "");
  EXPECT_INT(strcmp(sd_trajectory_strerror(-999), "unknown error"), 0,
             "a code outside the enum is unknown");
}

//---------------------------------- properties ---------------------------------------------------

static void interpolates_keyframes(void) {
  static double out[SD_MAX_DOF][3];
  fill_random(&g_tr, 9, 3, 105);
  if (!setup_ok(&g_tr)) return;
  double err[3] = {0, 0, 0};
  for (int k = 0; k < g_tr.nknot; k++) {
    eval_at(&g_tr, knot_time(&g_tr, k), out);
    for (int j = 0; j < g_tr.ndof; j++) {
      double scale[3];
      dof_scales(&g_tr, j, scale);
      worst_update(&err[0], fabs(out[j][0] - (double)g_tr.knot_q[k][j]));
      worst_update(&err[1], fabs(out[j][1] - (double)g_tr.knot_qd[k][j]) / scale[1]);
      worst_update(&err[2], fabs(out[j][2] - (double)g_tr.knot_qdd[k][j]) / scale[2]);
    }
  }
  EXPECT_LE(err[0], 0, "q(t_k) = knot_q exactly: the segment starts at s = 0, or the end is held");
  EXPECT_LE(err[1], TR_REL, "qd(t_k) = knot_qd (relative to Q / hmin)");
  EXPECT_LE(err[2], TR_REL, "qdd(t_k) = knot_qdd (relative to Q / hmin^2)");
}

static void rests_at_both_ends(void) {
  static double out[SD_MAX_DOF][3];
  fill_random(&g_tr, 7, 3, 106);
  if (!setup_ok(&g_tr)) return;
  int n = g_tr.nknot;
  double first = knot_time(&g_tr, 0), last = knot_time(&g_tr, n - 1);
  const double times[] = {first, last, first - 1, first - 1e-3, last + 1e-3, last + 5,
                          -INFINITY, INFINITY, NAN};
  const int held[] = {0, n - 1, 0, 0, n - 1, n - 1, 0, n - 1, 0};
  for (int c = 0; c < 9; c++) {
    eval_at(&g_tr, times[c], out);
    double dq = 0, rate = 0;
    for (int j = 0; j < g_tr.ndof; j++) {
      worst_update(&dq, fabs(out[j][0] - (double)g_tr.knot_q[held[c]][j]));
      worst_update(&rate, fabs(out[j][1]) + fabs(out[j][2]));
    }
    sdt_context("t = %g (keyframes from %g to %g s)", times[c], first, last);
    EXPECT_LE(dq, 0, held[c] ? "at and after the last keyframe q is the last keyframe"
                             : "at and before the first keyframe (or at NaN) q is the first");
    EXPECT_LE(rate, 0, "|qd| + |qdd| = 0 exactly: the trajectory starts and ends at rest");
  }
  for (int j = 0; j < g_tr.ndof; j++) {
    sdt_context("dof %d", j);
    EXPECT_LE(fabs((double)g_tr.knot_qdd[0][j]) + fabs((double)g_tr.knot_qdd[n-1][j]), 0,
              "the end keyframes have zero acceleration");
  }
}

// one-sided limits of q, qd, qdd at t_k from the side `side` (-1 left, +1 right): linear
// extrapolation from t_k + side delta and t_k + 2 side delta, which cancels the O(delta) slope
// term and leaves O(delta^2) plus rounding
static void one_sided_limit(const sd_trajectory* tr, int k, int side, double delta,
                            double lim[][3]) {
  static double y1[SD_MAX_DOF][3], y2[SD_MAX_DOF][3];
  double tk = knot_time(tr, k);
  double t1 = eval_at(tr, tk + side * delta, y1);
  double t2 = eval_at(tr, tk + 2 * side * delta, y2);
  double w = (tk - t1) / (t1 - t2);
  for (int j = 0; j < tr->ndof; j++) {
    for (int d = 0; d < 3; d++) lim[j][d] = y1[j][d] + (y1[j][d] - y2[j][d]) * w;
  }
}

static void continuous_to_second_derivative(void) {
  static double left[SD_MAX_DOF][3], right[SD_MAX_DOF][3];
  fill_random(&g_tr, 12, 3, 107);
  if (!setup_ok(&g_tr)) return;
  double delta = TR_DELTA * min_gap(&g_tr);
  double jump[3] = {0, 0, 0}, off[3] = {0, 0, 0};
  int worst_knot = -1;
  for (int k = 0; k < g_tr.nknot; k++) {
    one_sided_limit(&g_tr, k, -1, delta, left);
    one_sided_limit(&g_tr, k, +1, delta, right);
    for (int j = 0; j < g_tr.ndof; j++) {
      double scale[3], knot[3] = {(double)g_tr.knot_q[k][j], (double)g_tr.knot_qd[k][j],
                                  (double)g_tr.knot_qdd[k][j]};
      dof_scales(&g_tr, j, scale);
      for (int d = 0; d < 3; d++) {
        double e = fabs(left[j][d] - right[j][d]) / scale[d];
        if (e > jump[d]) worst_knot = k;
        worst_update(&jump[d], e);
        worst_update(&off[d], fabs(right[j][d] - knot[d]) / scale[d]);
      }
    }
  }
  sdt_context("12 keyframes incl. both ends, limits from t_k -+ %.3g s; worst jump at keyframe %d",
              delta, worst_knot);
  EXPECT_LE(jump[0], TR_REL, "q is continuous at every keyframe (left = right limit)");
  EXPECT_LE(jump[1], TR_REL, "qd is continuous at every keyframe (left = right limit)");
  EXPECT_LE(jump[2], TR_REL, "qdd is continuous at every keyframe: the curve is C2");
  EXPECT_LE(off[0], TR_REL, "the limit of q at a keyframe is knot_q");
  EXPECT_LE(off[1], TR_REL, "the limit of qd at a keyframe is knot_qd");
  EXPECT_LE(off[2], TR_REL, "the limit of qdd at a keyframe is knot_qdd");
}

static void derivatives_match_finite_differences(void) {
  static double y[SD_MAX_DOF][3], yp[SD_MAX_DOF][3], ym[SD_MAX_DOF][3];
  fill_random(&g_tr, 8, 3, 108);
  if (!setup_ok(&g_tr)) return;
  double err_qd = 0, err_qdd = 0;
  for (int i = 0; i < g_tr.nknot - 1; i++) {
    double t0 = knot_time(&g_tr, i), h = knot_time(&g_tr, i + 1) - t0, step = TR_FD_STEP * h;
    for (int m = 0; m < 5; m++) {
      double t = eval_at(&g_tr, t0 + h * (0.1 + 0.2 * m), y);
      double tp = eval_at(&g_tr, t + step, yp), tm = eval_at(&g_tr, t - step, ym);
      for (int j = 0; j < g_tr.ndof; j++) {
        double scale[3];
        dof_scales(&g_tr, j, scale);
        worst_update(&err_qd, fabs((yp[j][0] - ym[j][0]) / (tp - tm) - y[j][1]) / scale[1]);
        worst_update(&err_qdd, fabs((yp[j][1] - ym[j][1]) / (tp - tm) - y[j][2]) / scale[2]);
      }
    }
  }
  sdt_context("7 segments x 5 points x 3 dofs, step %.3g of the segment", TR_FD_STEP);
  EXPECT_LE(err_qd, TR_TOL_FD, "qd = (q(t+h) - q(t-h)) / 2h inside every segment");
  EXPECT_LE(err_qdd, TR_TOL_FD, "qdd = (qd(t+h) - qd(t-h)) / 2h inside every segment");
}

static void null_outputs_allowed(void) {
  sd_real q[SD_MAX_DOF], qd[SD_MAX_DOF], qdd[SD_MAX_DOF], x[SD_MAX_DOF];
  fill_random(&g_tr, 5, 3, 109);
  if (!setup_ok(&g_tr)) return;
  sd_real t = SD_R(0.5) * (g_tr.knot_t[1] + g_tr.knot_t[2]);
  sd_trajectory_eval(&g_tr, t, q, qd, qdd);
  sd_trajectory_eval(&g_tr, t, x, NULL, NULL);
  EXPECT_LE(sdt_maxdiff(x, q, 3), 0, "q alone (qd, qdd NULL) is the same q");
  sd_trajectory_eval(&g_tr, t, NULL, x, NULL);
  EXPECT_LE(sdt_maxdiff(x, qd, 3), 0, "qd alone (q, qdd NULL) is the same qd");
  sd_trajectory_eval(&g_tr, t, NULL, NULL, x);
  EXPECT_LE(sdt_maxdiff(x, qdd, 3), 0, "qdd alone (q, qd NULL) is the same qdd");
}

//---------------------------------- the math -----------------------------------------------------

static void two_keyframes_closed_form(void) {
  // no inner keyframe: v = a = 0 at both ends, q = q0 + D (10 s^3 - 15 s^4 + 6 s^5)
  static double out[SD_MAX_DOF][3];
  fill_random(&g_tr, 2, 3, 110);
  if (!setup_ok(&g_tr)) return;
  double t0 = knot_time(&g_tr, 0), h = knot_time(&g_tr, 1) - t0;
  double err[3] = {0, 0, 0};
  for (int m = 0; m <= 8; m++) {
    double s = (eval_at(&g_tr, t0 + h * m / 8, out) - t0) / h;
    for (int j = 0; j < 3; j++) {
      double q0 = (double)g_tr.knot_q[0][j], D = (double)g_tr.knot_q[1][j] - q0, scale[3];
      double want[3] = {q0 + D * s*s*s * (10 - 15*s + 6*s*s),
                        D * s*s * (30 - 60*s + 30*s*s) / h,
                        D * s * (60 - 180*s + 120*s*s) / (h*h)};
      dof_scales(&g_tr, j, scale);
      for (int d = 0; d < 3; d++) worst_update(&err[d], fabs(out[j][d] - want[d]) / scale[d]);
    }
  }
  EXPECT_LE(err[0], TR_REL, "two keyframes: q is the minimum-jerk quintic 10s^3 - 15s^4 + 6s^5");
  EXPECT_LE(err[1], TR_REL, "two keyframes: qd is its derivative");
  EXPECT_LE(err[2], TR_REL, "two keyframes: qdd is its second derivative");
}

static void three_keyframes_closed_form(void) {
  // one inner keyframe: the clamped spline's slope there solves one equation,
  //   2 (1/h0 + 1/h1) v1 = 3 (D0/h0^2 + D1/h1^2),
  // and its second derivative is that of either neighbouring cubic
  fill_random(&g_tr, 3, 3, 111);
  if (!setup_ok(&g_tr)) return;
  double h0 = knot_time(&g_tr, 1) - knot_time(&g_tr, 0);
  double h1 = knot_time(&g_tr, 2) - knot_time(&g_tr, 1);
  double err_v = 0, err_a = 0;
  for (int j = 0; j < 3; j++) {
    double q0 = (double)g_tr.knot_q[0][j], q1 = (double)g_tr.knot_q[1][j];
    double q2 = (double)g_tr.knot_q[2][j], scale[3];
    dof_scales(&g_tr, j, scale);
    double v1 = 3 * ((q1 - q0) / (h0*h0) + (q2 - q1) / (h1*h1)) / (2 * (1/h0 + 1/h1));
    double a_right = (6 * (q2 - q1) / h1 - 4 * v1) / h1;   // cubic from (q1, v1) to (q2, 0)
    double a_left = (-6 * (q1 - q0) / h0 + 4 * v1) / h0;   // cubic from (q0, 0) to (q1, v1)
    worst_update(&err_v, fabs((double)g_tr.knot_qd[1][j] - v1) / scale[1]);
    worst_update(&err_a, fabs((double)g_tr.knot_qdd[1][j] - a_right) / scale[2]);
    worst_update(&err_a, fabs((double)g_tr.knot_qdd[1][j] - a_left) / scale[2]);
  }
  sdt_context("gaps %.4g and %.4g s", h0, h1);
  EXPECT_LE(err_v, TR_REL, "one inner keyframe: v1 = 3 (D0/h0^2 + D1/h1^2) / (2 (1/h0 + 1/h1))");
  EXPECT_LE(err_a, TR_REL, "one inner keyframe: qdd there = that of the cubic on either side");
}

// p(tau) = off + amp (3 T tau^2 - 2 tau^3) / T^3 and its two derivatives
static void cubic_eval(double amp, double off, double T, double tau, double y[3]) {
  double T3 = T * T * T;
  y[0] = off + amp * (3*T*tau*tau - 2*tau*tau*tau) / T3;
  y[1] = amp * (6*T*tau - 6*tau*tau) / T3;
  y[2] = amp * (6*T - 12*tau) / T3;
}

static void reproduces_a_cubic(void) {
  // p has zero slope at tau = 0 and tau = T, so it is its own clamped cubic spline on any
  // keyframes: the inner segments must be p, and the end segments the quintic Hermite
  // polynomial from (q0, 0, 0) to (p, p', p'') at the next keyframe (and back to rest)
  static double out[SD_MAX_DOF][3];
  static const double w[8] = {0, 0.07, 0.25, 0.31, 0.5, 0.78, 0.9, 1.0};
  static const double amp[2] = {1.0, -2.5}, off[2] = {0.3, 1.0};
  const int n = 8;
  g_tr.nknot = n;
  g_tr.ndof = 2;
  for (int k = 0; k < n; k++) g_tr.knot_t[k] = (sd_real)(0.25 + 3.0 * w[k]);
  // p on the rounded times, so that its end slopes are zero at the keyframes the core sees
  double t0 = knot_time(&g_tr, 0), T = knot_time(&g_tr, n - 1) - t0, y[3];
  for (int k = 0; k < n; k++) {
    for (int j = 0; j < 2; j++) {
      cubic_eval(amp[j], off[j], T, knot_time(&g_tr, k) - t0, y);
      g_tr.knot_q[k][j] = (sd_real)y[0];
    }
  }
  if (!setup_ok(&g_tr)) return;

  // keyframe velocities everywhere, accelerations at the inner keyframes
  double err_v = 0, err_a = 0, err[3] = {0, 0, 0}, err_end[3] = {0, 0, 0};
  for (int j = 0; j < 2; j++) {
    double scale[3];
    dof_scales(&g_tr, j, scale);
    for (int k = 0; k < n; k++) {
      cubic_eval(amp[j], off[j], T, knot_time(&g_tr, k) - t0, y);
      worst_update(&err_v, fabs((double)g_tr.knot_qd[k][j] - y[1]) / scale[1]);
      if (k > 0 && k < n - 1) {
        worst_update(&err_a, fabs((double)g_tr.knot_qdd[k][j] - y[2]) / scale[2]);
      }
    }
  }
  EXPECT_LE(err_v, TR_REL, "knot_qd = p' at every keyframe: p is its own clamped spline");
  EXPECT_LE(err_a, TR_REL, "knot_qdd = p'' at every inner keyframe");

  // inner segments: p itself
  for (int i = 1; i < n - 2; i++) {
    double ti = knot_time(&g_tr, i), h = knot_time(&g_tr, i + 1) - ti;
    for (int m = 0; m <= 6; m++) {
      double t = eval_at(&g_tr, ti + h * m / 6, out);
      for (int j = 0; j < 2; j++) {
        double scale[3];
        cubic_eval(amp[j], off[j], T, t - t0, y);
        dof_scales(&g_tr, j, scale);
        for (int d = 0; d < 3; d++) worst_update(&err[d], fabs(out[j][d] - y[d]) / scale[d]);
      }
    }
  }
  EXPECT_LE(err[0], TR_REL, "inner segments: q = p (a cubic is the quintic of its own end data)");
  EXPECT_LE(err[1], TR_REL, "inner segments: qd = p'");
  EXPECT_LE(err[2], TR_REL, "inner segments: qdd = p''");

  // end segments: the quintic Hermite polynomial, solved here from its six conditions
  for (int j = 0; j < 2; j++) {
    double rest0[3] = {(double)g_tr.knot_q[0][j], 0, 0};
    double rest1[3] = {(double)g_tr.knot_q[n-1][j], 0, 0};
    double y1[3], y0[3];
    cubic_eval(amp[j], off[j], T, knot_time(&g_tr, 1) - t0, y1);
    cubic_eval(amp[j], off[j], T, knot_time(&g_tr, n - 2) - t0, y0);
    end_segment_error(&g_tr, j, 0, rest0, y1, err_end);
    end_segment_error(&g_tr, j, n - 2, y0, rest1, err_end);
  }
  EXPECT_LE(err_end[0], TR_REL, "end segments: q = the quintic from rest to (p, p', p'')");
  EXPECT_LE(err_end[1], TR_REL, "end segments: qd = that quintic's derivative");
  EXPECT_LE(err_end[2], TR_REL, "end segments: qdd = that quintic's second derivative");
}

static void matches_reference_spline(void) {
  static ref_spline ref;
  static double out[SD_MAX_DOF][3];
  const int cases[2][3] = {{9, 3, 112}, {SD_MAX_KNOT, 3, 113}};
  for (int c = 0; c < 2; c++) {
    int n = cases[c][0], nd = cases[c][1];
    fill_random(&g_tr, n, nd, (unsigned)cases[c][2]);
    if (!setup_ok(&g_tr)) return;
    double err_v = 0, err_a = 0, err[3] = {0, 0, 0}, err_end[3] = {0, 0, 0}, ref_end = 0;
    for (int j = 0; j < nd; j++) {
      double scale[3];
      dof_scales(&g_tr, j, scale);
      if (!EXPECT_INT(ref_spline_build(&ref, &g_tr, j), 0, "the reference system is regular")) {
        return;
      }
      double end_slopes = fabs(ref_spline_slope(&ref, 0)) + fabs(ref_spline_slope(&ref, n - 1));
      worst_update(&ref_end, end_slopes / scale[1]);

      // keyframe data
      for (int k = 0; k < n; k++) {
        double v = ref_spline_slope(&ref, k);
        worst_update(&err_v, fabs((double)g_tr.knot_qd[k][j] - v) / scale[1]);
        if (k > 0 && k < n - 1) {
          worst_update(&err_a, fabs((double)g_tr.knot_qdd[k][j] - ref.M[k]) / scale[2]);
        }
      }

      // inner segments: the spline
      for (int i = 1; i < n - 2; i++) {
        double ti = ref.t[i], h = ref.t[i+1] - ti;
        for (int m = 0; m < 5; m++) {
          double t = eval_at(&g_tr, ti + h * (0.05 + 0.225 * m), out), y[3];
          ref_spline_eval(&ref, i, t, y);
          for (int d = 0; d < 3; d++) worst_update(&err[d], fabs(out[j][d] - y[d]) / scale[d]);
        }
      }

      // end segments: from rest to the spline's (q, v, a) at the next keyframe, and back
      double rest0[3] = {ref.q[0], 0, 0}, rest1[3] = {ref.q[n-1], 0, 0};
      double y1[3] = {ref.q[1], ref_spline_slope(&ref, 1), ref.M[1]};
      double y0[3] = {ref.q[n-2], ref_spline_slope(&ref, n - 2), ref.M[n-2]};
      end_segment_error(&g_tr, j, 0, rest0, y1, err_end);
      end_segment_error(&g_tr, j, n - 2, y0, rest1, err_end);
    }
    sdt_context("%d keyframes, %d dofs, gaps 0.2..1 s, amplitudes 1, 0.02, 40", n, nd);
    EXPECT_LE(ref_end, 1e-9, "(the reference spline is clamped: zero slope at both ends)");
    EXPECT_LE(err_v, TR_REL, "knot_qd = the reference spline's slopes (dense moment solve)");
    EXPECT_LE(err_a, TR_REL, "knot_qdd = the reference spline's second derivatives (inner)");
    EXPECT_LE(err[0], TR_REL, "inner segments: q = the reference cubic spline");
    EXPECT_LE(err[1], TR_REL, "inner segments: qd = the reference spline's slope");
    EXPECT_LE(err[2], TR_REL, "inner segments: qdd = the reference spline's second derivative");
    EXPECT_LE(err_end[0], TR_REL, "end segments: q = the quintic Hermite from/to rest");
    EXPECT_LE(err_end[1], TR_REL, "end segments: qd = its derivative");
    EXPECT_LE(err_end[2], TR_REL, "end segments: qdd = its second derivative");
  }
}

const sdt_test sdt_trajectory_tests[] = {
  {"accepts_valid_trajectories", accepts_valid_trajectories},
  {"rejects_bad_input", rejects_bad_input},
  {"interpolates_keyframes", interpolates_keyframes},
  {"rests_at_both_ends", rests_at_both_ends},
  {"continuous_to_second_derivative", continuous_to_second_derivative},
  {"derivatives_match_finite_differences", derivatives_match_finite_differences},
  {"null_outputs_allowed", null_outputs_allowed},
  {"two_keyframes_closed_form", two_keyframes_closed_form},
  {"three_keyframes_closed_form", three_keyframes_closed_form},
  {"reproduces_a_cubic", reproduces_a_cubic},
  {"matches_reference_spline", matches_reference_spline},
  {0, 0},
};
