// trajectory.c: keyframe trajectories, C2 quintic segments on the clamped cubic spline.
//
// Setup solves for the slopes v_i of the cubic spline through the keyframes with v = 0 at both
// ends, takes its second derivatives a_i at the inner keyframes, and sets a = 0 at both ends.
// Segment i (from keyframe i to i+1, length h) is then, in the normalized time s = (t - t_i)/h,
// the quintic Hermite polynomial with position, velocity and acceleration (q, v, a) at both ends:
//
//   q(s) = H(s) + 1/2 s^2 (1-s)^2 ((1-s) e0 + s e1)
//
// where H is the cubic Hermite polynomial with the end positions and slopes (V = v h), and
// e0, e1 are the differences between the wanted end accelerations (A = a h^2) and those of H.
// The correction term and its first derivative vanish at both ends and its second derivative is
// e0 at s = 0 and e1 at s = 1, so q matches all six conditions; a quintic is fixed by six, so
// this is the quintic Hermite polynomial.
//
// Why the inner segments are the cubic spline: on a segment between two inner keyframes the
// spline itself is a cubic with end values q, end slopes v and, because the spline is C2, end
// second derivatives a_i and a_{i+1}. A cubic is a quintic (with zero s^4 and s^5 terms) that
// meets the same six Hermite conditions as our segment, and the quintic meeting six Hermite
// conditions is unique, so the segment is that cubic: here H itself, with e0 = e1 = 0 up to
// rounding. Only the first and last segments differ from the spline, because their end
// acceleration was set to zero; they still join the inner segments with matching q, v and a.
#include "sd_trajectory.h"

int sd_trajectory_setup(sd_trajectory* tr, int* bad_knot, int* bad_dof) {
  int dummy_knot, dummy_dof;
  if (!bad_knot) {
    bad_knot = &dummy_knot;
  }
  if (!bad_dof) {
    bad_dof = &dummy_dof;
  }
  *bad_knot = -1;
  *bad_dof = -1;
  int n = tr->nknot, nd = tr->ndof;
  if (n < 2 || n > SD_MAX_KNOT || nd < 1 || nd > SD_MAX_DOF) {
    return SD_ERR_KNOTS;
  }

  // times: finite, strictly increasing, and gaps whose 1/h^2 (in the accelerations) is finite
  const sd_real* t = tr->knot_t;
  for (int k = 0; k < n; k++) {
    if (!SD_ISFINITE(t[k])) {
      *bad_knot = k;
      return SD_ERR_TIME;
    }
    if (k > 0) {
      sd_real h = t[k] - t[k-1];
      sd_real inv_h2 = SD_R(1) / (h * h);
      if (!(h > 0) || !SD_ISFINITE(h) || !SD_ISFINITE(inv_h2)) {
        *bad_knot = k;
        return SD_ERR_TIME;
      }
    }
  }

  // positions: finite
  for (int k = 0; k < n; k++) {
    for (int j = 0; j < nd; j++) {
      if (!SD_ISFINITE(tr->knot_q[k][j])) {
        *bad_knot = k;
        *bad_dof = j;
        return SD_ERR_KNOTVALUE;
      }
    }
  }

  // the spline's slopes solve, at each inner keyframe i (v_0 = v_{n-1} = 0 are known),
  //   v_{i-1} / h_{i-1} + 2 (1/h_{i-1} + 1/h_i) v_i + v_{i+1} / h_i
  //     = 3 ((q_i - q_{i-1}) / h_{i-1}^2 + (q_{i+1} - q_i) / h_i^2),
  // which says the second derivatives of the two cubics meeting at i agree; h_i = t_{i+1} - t_i
  // may vary. The matrix is strictly diagonally dominant, so the Thomas algorithm (elimination
  // without pivoting) is stable. It depends on the times alone: one sweep over the keyframes
  // eliminates all dofs at once, keeping only the eliminated upper diagonal for the way back
  sd_real upper[SD_MAX_KNOT];      // upper diagonal over the pivot after elimination
  upper[0] = 0;
  for (int j = 0; j < nd; j++) {
    tr->knot_qd[0][j] = 0;         // row 0 is the known v_0 = 0
    tr->knot_qd[n-1][j] = 0;
  }
  for (int i = 1; i < n - 1; i++) {
    sd_real inv_h0 = SD_R(1) / (t[i] - t[i-1]), inv_h1 = SD_R(1) / (t[i+1] - t[i]);
    sd_real inv_pivot = SD_R(1) / (SD_R(2) * (inv_h0 + inv_h1) - inv_h0 * upper[i-1]);
    upper[i] = inv_h1 * inv_pivot;
    for (int j = 0; j < nd; j++) {
      sd_real slope0 = (tr->knot_q[i][j] - tr->knot_q[i-1][j]) * inv_h0;
      sd_real slope1 = (tr->knot_q[i+1][j] - tr->knot_q[i][j]) * inv_h1;
      sd_real rhs = SD_R(3) * (slope0 * inv_h0 + slope1 * inv_h1);
      tr->knot_qd[i][j] = (rhs - inv_h0 * tr->knot_qd[i-1][j]) * inv_pivot;
    }
  }
  // back substitution from the known v_{n-1} = 0
  for (int i = n - 2; i >= 1; i--) {
    for (int j = 0; j < nd; j++) {
      tr->knot_qd[i][j] -= upper[i] * tr->knot_qd[i+1][j];
    }
  }

  // second derivative at each inner keyframe: the mean of those of the cubics on its left and
  // right (equal up to rounding); zero at both ends, where the trajectory starts and ends at rest
  for (int j = 0; j < nd; j++) {
    tr->knot_qdd[0][j] = 0;
    tr->knot_qdd[n-1][j] = 0;
  }
  for (int i = 1; i < n - 1; i++) {
    sd_real inv_h0 = SD_R(1) / (t[i] - t[i-1]), inv_h1 = SD_R(1) / (t[i+1] - t[i]);
    for (int j = 0; j < nd; j++) {
      sd_real slope0 = (tr->knot_q[i][j] - tr->knot_q[i-1][j]) * inv_h0;
      sd_real slope1 = (tr->knot_q[i+1][j] - tr->knot_q[i][j]) * inv_h1;
      sd_real v0 = tr->knot_qd[i-1][j], v = tr->knot_qd[i][j], v1 = tr->knot_qd[i+1][j];
      sd_real left = (SD_R(-6) * slope0 + SD_R(2) * v0 + SD_R(4) * v) * inv_h0;
      sd_real right = (SD_R(6) * slope1 - SD_R(4) * v - SD_R(2) * v1) * inv_h1;
      tr->knot_qdd[i][j] = SD_R(0.5) * (left + right);
    }
  }

  // derived numbers: finite (huge positions over tiny gaps overflow)
  for (int k = 0; k < n; k++) {
    for (int j = 0; j < nd; j++) {
      if (!SD_ISFINITE(tr->knot_qd[k][j]) || !SD_ISFINITE(tr->knot_qdd[k][j])) {
        *bad_knot = k;
        *bad_dof = j;
        return SD_ERR_SPLINE;
      }
    }
  }
  return 0;  // SD_OK
}

void sd_trajectory_eval(const sd_trajectory* tr, sd_real t, sd_real* q, sd_real* qd,
                        sd_real* qdd) {
  int n = tr->nknot, nd = tr->ndof;
  const sd_real* knot_t = tr->knot_t;

  // outside the time span hold the first or last keyframe at rest (a NaN t fails t > t_0)
  if (!(t > knot_t[0]) || t >= knot_t[n-1]) {
    int k = (t >= knot_t[n-1]) ? n - 1 : 0;
    for (int j = 0; j < nd; j++) {
      if (q) q[j] = tr->knot_q[k][j];
      if (qd) qd[j] = 0;
      if (qdd) qdd[j] = 0;
    }
    return;
  }

  // binary search for the segment with knot_t[lo] <= t < knot_t[hi]: hi - lo halves each pass,
  // so at most log2(SD_MAX_KNOT) passes
  int lo = 0, hi = n - 1;
  while (hi - lo > 1) {
    int mid = lo + (hi - lo) / 2;
    if (t < knot_t[mid]) {
      hi = mid;
    } else {
      lo = mid;
    }
  }

  sd_trajectory_segment(nd, knot_t[lo], knot_t[hi], tr->knot_q[lo], tr->knot_qd[lo], tr->knot_qdd[lo],
                        tr->knot_q[hi], tr->knot_qd[hi], tr->knot_qdd[hi], t, q, qd, qdd);
}

void sd_trajectory_segment(int nd, sd_real t0, sd_real t1, const sd_real* q0, const sd_real* qd0,
                           const sd_real* qdd0, const sd_real* q1, const sd_real* qd1, const sd_real* qdd1,
                           sd_real t, sd_real* q, sd_real* qd, sd_real* qdd) {
  // normalized time s in [0, 1): d/dt = (1/h) d/ds
  sd_real h = t1 - t0;
  sd_real inv_h = SD_R(1) / h;
  sd_real s = (t - t0) * inv_h;
  for (int j = 0; j < nd; j++) {
    // end data in s: positions, slopes V = v h, accelerations A = a h^2
    sd_real p0 = q0[j], p1 = q1[j];
    sd_real d = p1 - p0;
    sd_real v0 = qd0[j] * h, v1 = qd1[j] * h;
    sd_real a0 = qdd0[j] * h * h, a1 = qdd1[j] * h * h;

    // e0, e1: wanted end accelerations minus those of the cubic Hermite H
    sd_real e0 = a0 - (SD_R(6) * d - SD_R(4) * v0 - SD_R(2) * v1);
    sd_real e1 = a1 - (SD_R(-6) * d + SD_R(2) * v0 + SD_R(4) * v1);

    // monomial coefficients of H(s) + 1/2 s^2 (1-s)^2 ((1-s) e0 + s e1)
    sd_real c1 = v0;
    sd_real c2 = SD_R(3) * d - SD_R(2) * v0 - v1 + SD_R(0.5) * e0;
    sd_real c3 = SD_R(-2) * d + v0 + v1 + SD_R(0.5) * (e1 - SD_R(3) * e0);
    sd_real c4 = SD_R(0.5) * (SD_R(3) * e0 - SD_R(2) * e1);
    sd_real c5 = SD_R(0.5) * (e1 - e0);

    // Horner for the quintic and its two derivatives
    if (q) {
      q[j] = p0 + s * (c1 + s * (c2 + s * (c3 + s * (c4 + s * c5))));
    }
    if (qd) {
      sd_real dq = c1 + s * (SD_R(2) * c2 + s * (SD_R(3) * c3 + s * (SD_R(4) * c4
                   + s * SD_R(5) * c5)));
      qd[j] = dq * inv_h;
    }
    if (qdd) {
      sd_real ddq = SD_R(2) * c2 + s * (SD_R(6) * c3 + s * (SD_R(12) * c4 + s * SD_R(20) * c5));
      qdd[j] = ddq * inv_h * inv_h;
    }
  }
}

const char* sd_trajectory_strerror(int code) {
  switch (code) {
    case 0:                return "ok";
    case SD_ERR_KNOTS:     return "number of keyframes outside 2..SD_MAX_KNOT or of dofs outside "
                                  "1..SD_MAX_DOF";
    case SD_ERR_TIME:      return "keyframe times must be finite and strictly increasing, with "
                                  "gaps whose inverse square is finite";
    case SD_ERR_KNOTVALUE: return "a NaN or infinite keyframe position";
    case SD_ERR_SPLINE:    return "a keyframe velocity or acceleration overflows: positions too "
                                  "large for the spacing of the keyframes";
    default:               return "unknown error";
  }
}
