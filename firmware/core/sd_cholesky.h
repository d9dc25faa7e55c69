// sd_cholesky.h (internal): the Cholesky factor D = L L' of a small symmetric positive
// semidefinite matrix and the solves with it, for a joint's D = S' IA S (n <= 3) and a free root's
// articulated inertia (n = 6).
//
// Matrices are row-major with row stride ld; L is the lower triangle, its diagonal stored as
// reciprocals so that the solves multiply. Solving with the factor keeps the precision an explicit
// inverse loses when a joint's axes are nearly parallel. n and ld are literals at every call.
#ifndef SD_CHOLESKY_H
#define SD_CHOLESKY_H

#include "sd_config.h"

// Factor D = L L' (L may be D itself). At a gimbal lock two axes of a joint coincide and D is
// singular: the pivot of the later axis vanishes, and that dof is dropped (zero reciprocal and
// column, so its solution is 0) while the others carry the motion exactly. Returns the number of
// dofs dropped; *min_pivot gets the smallest pivot relative to its diagonal entry (1 for
// orthogonal axes, near 0 near a lock).
static inline int sd_cholesky(sd_real* L, const sd_real* D, const int n, const int ld,
                              sd_real* min_pivot) {
  int dropped = 0;
  *min_pivot = 1;
  for (int j = 0; j < n; j++) {
    // the pivot: what D's diagonal keeps after the earlier columns
    sd_real diag = D[(ld + 1)*j];
    for (int k = 0; k < j; k++) {
      diag -= L[ld*j + k] * L[ld*j + k];
    }

    // a vanishing pivot: drop the dof
    if (!(diag > SD_R(64) * SD_EPS * D[(ld + 1)*j])) {
      dropped++;
      L[(ld + 1)*j] = 0;
      for (int i = j + 1; i < n; i++) {
        L[ld*i + j] = 0;
      }
      continue;
    }
    if (diag < *min_pivot * D[(ld + 1)*j]) {
      *min_pivot = diag / D[(ld + 1)*j];
    }

    // the column below the pivot
    sd_real ljj = sd_sqrt(diag);
    L[(ld + 1)*j] = SD_R(1) / ljj;
    for (int i = j + 1; i < n; i++) {
      sd_real s = D[ld*i + j];
      for (int k = 0; k < j; k++) {
        s -= L[ld*i + k] * L[ld*j + k];
      }
      L[ld*i + j] = s / ljj;
    }
  }
  return dropped;
}

// x = L^-1 x, the first half of a solve
static inline void sd_cholesky_forward(const sd_real* L, const int n, const int ld, sd_real* x) {
  for (int i = 0; i < n; i++) {
    for (int k = 0; k < i; k++) {
      x[i] -= L[ld*i + k] * x[k];
    }
    x[i] *= L[(ld + 1)*i];
  }
}

// x = D^-1 x = L'^-1 L^-1 x
static inline void sd_cholesky_solve(const sd_real* L, const int n, const int ld, sd_real* x) {
  sd_cholesky_forward(L, n, ld, x);
  for (int i = n - 1; i >= 0; i--) {
    for (int k = i + 1; k < n; k++) {
      x[i] -= L[ld*k + i] * x[k];
    }
    x[i] *= L[(ld + 1)*i];
  }
}

#endif  // SD_CHOLESKY_H
