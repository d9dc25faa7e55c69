// sd_math.h (internal): small fixed-size vector and matrix helpers shared by the core's
// algorithms.
// Everything is static inline: no calls in the hot paths, no state.
#ifndef SD_MATH_H
#define SD_MATH_H

#include "sd_config.h"

//---------------------------------- 3-vectors ---------------------------------------------------

// r = 0
static inline void sd_zero3(sd_real r[3]) {
  r[0] = 0; r[1] = 0; r[2] = 0;
}

// r = a
static inline void sd_copy3(sd_real r[3], const sd_real a[3]) {
  r[0] = a[0]; r[1] = a[1]; r[2] = a[2];
}

// r = a s
static inline void sd_scl3(sd_real r[3], const sd_real a[3], sd_real s) {
  r[0] = a[0]*s; r[1] = a[1]*s; r[2] = a[2]*s;
}

// r += a
static inline void sd_addto3(sd_real r[3], const sd_real a[3]) {
  r[0] += a[0]; r[1] += a[1]; r[2] += a[2];
}

// r -= a
static inline void sd_subfrom3(sd_real r[3], const sd_real a[3]) {
  r[0] -= a[0]; r[1] -= a[1]; r[2] -= a[2];
}

// r += a s
static inline void sd_addtoscl3(sd_real r[3], const sd_real a[3], sd_real s) {
  r[0] += a[0]*s; r[1] += a[1]*s; r[2] += a[2]*s;
}

// r = a x b
static inline void sd_cross(sd_real r[3], const sd_real a[3], const sd_real b[3]) {
  sd_real x = a[1]*b[2] - a[2]*b[1];
  sd_real y = a[2]*b[0] - a[0]*b[2];
  sd_real z = a[0]*b[1] - a[1]*b[0];
  r[0] = x; r[1] = y; r[2] = z;
}

// r += a x b
static inline void sd_addcross(sd_real r[3], const sd_real a[3], const sd_real b[3]) {
  r[0] += a[1]*b[2] - a[2]*b[1];
  r[1] += a[2]*b[0] - a[0]*b[2];
  r[2] += a[0]*b[1] - a[1]*b[0];
}

// a . b
static inline sd_real sd_dot(const sd_real a[3], const sd_real b[3]) {
  return a[0]*b[0] + a[1]*b[1] + a[2]*b[2];
}

//---------------------------------- 3x3 matrices ------------------------------------------------

// r = R v
static inline void sd_mulmv(sd_real r[3], const sd_real R[9], const sd_real v[3]) {
  sd_real x = R[0]*v[0] + R[1]*v[1] + R[2]*v[2];
  sd_real y = R[3]*v[0] + R[4]*v[1] + R[5]*v[2];
  sd_real z = R[6]*v[0] + R[7]*v[1] + R[8]*v[2];
  r[0] = x; r[1] = y; r[2] = z;
}

// r = R' v
static inline void sd_mulmtv(sd_real r[3], const sd_real R[9], const sd_real v[3]) {
  sd_real x = R[0]*v[0] + R[3]*v[1] + R[6]*v[2];
  sd_real y = R[1]*v[0] + R[4]*v[1] + R[7]*v[2];
  sd_real z = R[2]*v[0] + R[5]*v[1] + R[8]*v[2];
  r[0] = x; r[1] = y; r[2] = z;
}

// r = A B (r may not alias A or B)
static inline void sd_mulmm(sd_real r[9], const sd_real A[9], const sd_real B[9]) {
  for (int i = 0; i < 3; i++) {
    for (int j = 0; j < 3; j++) {
      r[3*i+j] = A[3*i]*B[j] + A[3*i+1]*B[3+j] + A[3*i+2]*B[6+j];
    }
  }
}

// r = Rz(q)' A = rows (c*A0 + s*A1, -s*A0 + c*A1, A2): rotate the frame of A about its z axis
static inline void sd_rotz_t_mul(sd_real r[9], sd_real c, sd_real s, const sd_real A[9]) {
  for (int j = 0; j < 3; j++) {
    sd_real a0 = A[j], a1 = A[3+j];
    r[j] = c*a0 + s*a1;
    r[3+j] = c*a1 - s*a0;
    r[6+j] = A[6+j];
  }
}

// symmetric 3x3 stored as xx yy zz xy xz yz: r = S v
static inline void sd_mulsym(sd_real r[3], const sd_real S[6], const sd_real v[3]) {
  sd_real x = S[0]*v[0] + S[3]*v[1] + S[4]*v[2];
  sd_real y = S[3]*v[0] + S[1]*v[1] + S[5]*v[2];
  sd_real z = S[4]*v[0] + S[5]*v[1] + S[2]*v[2];
  r[0] = x; r[1] = y; r[2] = z;
}

//---------------------------------- friction ----------------------------------------------------

// The friction torque a joint's model gives at speed qd: F_c tanh(qd / speed) + F_v qd, the
// Coulomb step smoothed over `speed` (control.c says why); speed is unused when coulomb is 0
static inline sd_real sd_friction(sd_real coulomb, sd_real viscous, sd_real speed, sd_real qd) {
  sd_real tau = viscous * qd;
  if (coulomb > 0) {
    tau += coulomb * sd_tanh(qd / speed);
  }
  return tau;
}

//---------------------------------- checks ------------------------------------------------------

// 1 when the n numbers of x are all finite
static inline int sd_allfinite(const sd_real* x, int n) {
  sd_real acc = 0;
  for (int i = 0; i < n; i++) {
    acc += x[i] - x[i];
  }
  return acc == 0;
}

#endif  // SD_MATH_H
