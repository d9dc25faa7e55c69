// sd_spatial.h (internal): spatial transforms between a body and its parent, and the
// articulated-inertia algebra of sd_forward.
//
// Body i sits at p = body_pos in its parent's frame, turned by R = body_R_parent; X is that
// transform (Featherstone's Xup). A motion is (angular; linear), a force (moment; force), both at
// the body origin in the body frame, kept as two 3-vectors. An articulated inertia IA is 21
// numbers, the blocks of [A B; B' C]: A and C symmetric (xx yy zz xy xz yz), B full (row-major).
// Everything is static inline; arguments named nz or nd are literals at every call, so each case
// compiles to its own unrolled code.
#ifndef SD_SPATIAL_H
#define SD_SPATIAL_H

#include "sd_math.h"

// a symmetric 3x3 stored as xx yy zz xy xz yz: entry e is (sd_sym_row[e], sd_sym_col[e]), and
// entry (r, c) is sd_sym_index[r][c]; loops run over e in storage order, which vectorizes
static const int sd_sym_row[6] = {0, 1, 2, 0, 0, 1}, sd_sym_col[6] = {0, 1, 2, 1, 2, 2};
static const int sd_sym_index[3][3] = {{0, 3, 4}, {3, 1, 5}, {4, 5, 2}};

//---------------------------------- transforms --------------------------------------------------

// (ang; lin) = X (ang_p; lin_p) = (R ang_p; R (lin_p + ang_p x p)): a parent's motion at the body
static inline void sd_xmotion(sd_real ang[3], sd_real lin[3], const sd_real R[9],
                              const sd_real p[3], const sd_real ang_p[3], const sd_real lin_p[3]) {
  sd_real t[3];
  sd_cross(t, ang_p, p);
  sd_addto3(t, lin_p);
  sd_mulmv(ang, R, ang_p);
  sd_mulmv(lin, R, t);
}

// (n_p; f_p) += X' (n; f) = (R' n + p x R' f; R' f): a body's force handed to its parent
static inline void sd_addto_xtforce(sd_real n_p[3], sd_real f_p[3], const sd_real R[9],
                                    const sd_real p[3], const sd_real n[3], const sd_real f[3]) {
  sd_real fp[3], np[3];
  sd_mulmtv(fp, R, f);
  sd_mulmtv(np, R, n);
  sd_addcross(np, p, fp);
  sd_addto3(n_p, np);
  sd_addto3(f_p, fp);
}

//---------------------------------- rotations of 3x3 blocks -------------------------------------

// r = R' S R for a symmetric S whose rows and columns from nz on are zero
static inline void sd_rotate_sym(sd_real r[6], const sd_real R[9], const sd_real S[6],
                                 const int nz) {
  // T = S R, its first nz rows
  sd_real T[9];
  for (int j = 0; j < 3; j++) {
    for (int k = 0; k < nz; k++) {
      sd_real s = S[sd_sym_index[k][0]] * R[j];
      for (int l = 1; l < nz; l++) {
        s += S[sd_sym_index[k][l]] * R[3*l + j];
      }
      T[3*k + j] = s;
    }
  }
  // r = R' T, the upper triangle
  for (int e = 0; e < 6; e++) {
    int i = sd_sym_row[e], j = sd_sym_col[e];
    sd_real s = R[i] * T[j];
    for (int k = 1; k < nz; k++) {
      s += R[3*k + i] * T[3*k + j];
    }
    r[e] = s;
  }
}

// r = R' M R for a full M whose rows from nz on are zero
static inline void sd_rotate_full(sd_real r[9], const sd_real R[9], const sd_real M[9],
                                  const int nz) {
  // T = M R, its first nz rows
  sd_real T[9];
  for (int j = 0; j < 3; j++) {
    for (int k = 0; k < nz; k++) {
      T[3*k + j] = M[3*k]*R[j] + M[3*k + 1]*R[3 + j] + M[3*k + 2]*R[6 + j];
    }
  }
  // r = R' T
  for (int i = 0; i < 3; i++) {
    for (int j = 0; j < 3; j++) {
      sd_real s = R[i] * T[j];
      for (int k = 1; k < nz; k++) {
        s += R[3*k + i] * T[3*k + j];
      }
      r[3*i + j] = s;
    }
  }
}

//---------------------------------- articulated inertia -----------------------------------------

// the rigid inertia about the body origin, [I h x; (h x)' m], with h = m com the first moment
static inline void sd_ia_rigid(sd_real IA[21], sd_real mass, const sd_real h[3],
                               const sd_real I[6]) {
  for (int k = 0; k < 6; k++) {
    IA[k] = I[k];
  }
  IA[6] = 0;      IA[7] = -h[2]; IA[8] = h[1];
  IA[9] = h[2];   IA[10] = 0;    IA[11] = -h[0];
  IA[12] = -h[1]; IA[13] = h[0]; IA[14] = 0;
  IA[15] = IA[16] = IA[17] = mass;
  IA[18] = IA[19] = IA[20] = 0;
}

// U = IA (z; 0) = (A z; B' z): the inertia times a rotation axis
static inline void sd_ia_mulaxis(sd_real U[6], const sd_real IA[21], const sd_real z[3]) {
  sd_mulsym(U, IA, z);
  sd_mulmtv(U + 3, IA + 6, z);
}

// U = IA (0, 0, 1; 0): the third column, for a rotation about z
static inline void sd_ia_mulzaxis(sd_real U[6], const sd_real IA[21]) {
  U[0] = IA[4];  U[1] = IA[5];  U[2] = IA[2];
  U[3] = IA[12]; U[4] = IA[13]; U[5] = IA[14];
}

// r += IA v
static inline void sd_ia_addtomul(sd_real r[6], const sd_real IA[21], const sd_real v[6]) {
  sd_real Av[3], Cv[3];
  sd_mulsym(Av, IA, v);
  sd_mulsym(Cv, IA + 15, v + 3);
  for (int i = 0; i < 3; i++) {
    const sd_real* Bi = IA + 6 + 3*i;
    r[i] += Av[i] + Bi[0]*v[3] + Bi[1]*v[4] + Bi[2]*v[5];
    r[3 + i] += Cv[i] + IA[6 + i]*v[0] + IA[9 + i]*v[1] + IA[12 + i]*v[2];
  }
}

// IA -= w x', for a w x' known to be symmetric (only the stored entries are formed)
static inline void sd_ia_subouter(sd_real IA[21], const sd_real w[6], const sd_real x[6]) {
  for (int e = 0; e < 6; e++) {
    int i = sd_sym_row[e], j = sd_sym_col[e];
    IA[e] -= w[i] * x[j];
    IA[15 + e] -= w[3 + i] * x[3 + j];
  }
  for (int i = 0; i < 3; i++) {
    for (int j = 0; j < 3; j++) {
      IA[6 + 3*i + j] -= w[i] * x[3 + j];
    }
  }
}

// IA_p += X' Ia X: the inertia Ia of a body that its nd-dof joint has been projected out of,
// handed to the parent. Rotate the blocks to the parent's axes (A', B', C'), then move the origin
// by p, with P the cross-product matrix of p:
//   C_p = C', B_p = B' + P C', A_p = A' + P M' + M P' where M = B' + P C' / 2
// (the last is A' + P B'' + B' P' + P C' P', written to need one product fewer).
// When Ia S = 0 for the joint's motion S (complete: no armature, and for 3 dofs well away from
// the lock) it zeroes blocks that then need no rotation: behind a 1-dof joint (about z) A's third
// row and column and B's third row, behind a 3-dof joint all of A and B.
static inline void sd_ia_addto_parent(sd_real IAp[21], const sd_real Ia[21], const sd_real R[9],
                                      const sd_real p[3], const int nd, int complete) {
  // the blocks in the parent's axes
  sd_real A[6] = {0, 0, 0, 0, 0, 0}, B[9] = {0, 0, 0, 0, 0, 0, 0, 0, 0}, C[6];
  if (nd == 1 && complete) {
    sd_rotate_sym(A, R, Ia, 2);
    sd_rotate_full(B, R, Ia + 6, 2);
  } else if (nd != 3 || !complete) {
    sd_rotate_sym(A, R, Ia, 3);
    sd_rotate_full(B, R, Ia + 6, 3);
  }
  sd_rotate_sym(C, R, Ia + 15, 3);

  // P C': p crossed with the columns of C'
  sd_real PC[9], M[9], N[9], pc[3];
  for (int j = 0; j < 3; j++) {
    sd_real col[3] = {C[sd_sym_index[0][j]], C[sd_sym_index[1][j]], C[sd_sym_index[2][j]]};
    sd_cross(pc, p, col);
    PC[j] = pc[0]; PC[3 + j] = pc[1]; PC[6 + j] = pc[2];
  }
  for (int k = 0; k < 9; k++) {
    M[k] = B[k] + SD_R(0.5) * PC[k];
  }

  // N = P M': column j is p x (row j of M)
  for (int j = 0; j < 3; j++) {
    sd_cross(pc, p, M + 3*j);
    N[j] = pc[0]; N[3 + j] = pc[1]; N[6 + j] = pc[2];
  }

  // accumulate into the parent
  for (int e = 0; e < 6; e++) {
    int i = sd_sym_row[e], j = sd_sym_col[e];
    IAp[e] += A[e] + N[3*i + j] + N[3*j + i];
    IAp[15 + e] += C[e];
  }
  for (int k = 0; k < 9; k++) {
    IAp[6 + k] += B[k] + PC[k];
  }
}

// the full 6x6 matrix (row-major) of IA
static inline void sd_ia_full(sd_real M[36], const sd_real IA[21]) {
  for (int e = 0; e < 6; e++) {
    int r = sd_sym_row[e], c = sd_sym_col[e];
    M[6*r + c] = M[6*c + r] = IA[e];
    M[6*(r + 3) + c + 3] = M[6*(c + 3) + r + 3] = IA[15 + e];
  }
  for (int r = 0; r < 3; r++) {
    for (int c = 0; c < 3; c++) {
      M[6*r + c + 3] = M[6*(c + 3) + r] = IA[6 + 3*r + c];
    }
  }
}

#endif  // SD_SPATIAL_H
