// ag.c: direct dynamics by the Armstrong-Green recursion (paper §3.1), in its exact O(n) form:
// an inbound pass (leaves to root) accumulates each body's articulated inertia IA and bias
// wrench pA, an outbound pass (root to leaves) yields the accelerations. Where Armstrong and Green
// assume a 3-dof joint and the paper projects with eq. 3.1, this divides by the articulated
// inertia about the joint's own free axes, D = S' IA S (at most 3x3), which is exact for 1-, 2-
// and 3-dof joints (Featherstone's articulated-body algorithm; his names: S, c, IA, pA, U, D, u).
//
// Spatial vectors are (angular; linear) at the body origin in the body frame. IA is stored as
// three 3x3 blocks [A B; B' C] with A and C symmetric (xx yy zz xy xz yz) and B full.
#include "servodyn.h"
#include "sd_joint.h"

static const int sym_row[6] = {0, 1, 2, 0, 0, 1}, sym_col[6] = {0, 1, 2, 1, 2, 2};

// r = R' S R for a symmetric S (xx yy zz xy xz yz), into the same storage
static inline void rotate_sym(sd_real r[6], const sd_real R[9], const sd_real S[6]) {
  sd_real T[9];
  for (int j = 0; j < 3; j++) {
    T[j] = S[0]*R[j] + S[3]*R[3+j] + S[4]*R[6+j];
    T[3+j] = S[3]*R[j] + S[1]*R[3+j] + S[5]*R[6+j];
    T[6+j] = S[4]*R[j] + S[5]*R[3+j] + S[2]*R[6+j];
  }
  for (int e = 0; e < 6; e++) {
    int i = sym_row[e], j = sym_col[e];
    r[e] = R[i]*T[j] + R[3+i]*T[3+j] + R[6+i]*T[6+j];
  }
}

// r = R' M R for a full M
static inline void rotate_full(sd_real r[9], const sd_real R[9], const sd_real M[9]) {
  sd_real T[9];
  sd_mulmm(T, M, R);
  for (int i = 0; i < 3; i++) {
    for (int j = 0; j < 3; j++) {
      r[3*i+j] = R[i]*T[j] + R[3+i]*T[3+j] + R[6+i]*T[6+j];
    }
  }
}

// r = R' S R for a symmetric S whose third row and column are zero (xx yy xy only)
static inline void rotate_sym_xy(sd_real r[6], const sd_real R[9], const sd_real S[6]) {
  sd_real T[6];
  for (int j = 0; j < 3; j++) {
    T[j] = S[0]*R[j] + S[3]*R[3+j];
    T[3+j] = S[3]*R[j] + S[1]*R[3+j];
  }
  for (int e = 0; e < 6; e++) {
    int i = sym_row[e], j = sym_col[e];
    r[e] = R[i]*T[j] + R[3+i]*T[3+j];
  }
}

// r = R' M R for an M whose third row is zero
static inline void rotate_rows01(sd_real r[9], const sd_real R[9], const sd_real M[9]) {
  sd_real T[6];
  for (int j = 0; j < 3; j++) {
    T[j] = M[0]*R[j] + M[1]*R[3+j] + M[2]*R[6+j];
    T[3+j] = M[3]*R[j] + M[4]*R[3+j] + M[5]*R[6+j];
  }
  for (int i = 0; i < 3; i++) {
    for (int j = 0; j < 3; j++) {
      r[3*i+j] = R[i]*T[j] + R[3+i]*T[3+j];
    }
  }
}

// IA_parent += X' Ia X for the joint of rotation R (body_R_parent) at p in the parent:
// rotate the blocks to the parent's axes (A', B', C'), then move the origin by p, with P the
// cross-product matrix of p:
//   C_p = C', B_p = B' + P C', A_p = A' + P M' + M P' where M = B' + P C' / 2
// (the last is A' + P B'' + B' P' + P C' P', written to need one product fewer).
// Ia S = 0 for the joint's motion S, which zeroes blocks that then need no rotation: behind a
// 1-dof joint (about z) A's third row and column and B's third row, behind a 3-dof joint well
// away from its lock (complete) all of A and B; nd is a literal, so each case compiles to its
// own code.
static inline void add_articulated_inertia(sd_real IAp[21], const sd_real Ia[21],
                                           const sd_real R[9], const sd_real p[3], const int nd,
                                           int complete) {
  sd_real A[6] = {0, 0, 0, 0, 0, 0}, B[9] = {0, 0, 0, 0, 0, 0, 0, 0, 0};
  sd_real C[6], PC[9], M[9], N[9];
  if (nd == 1) {
    rotate_sym_xy(A, R, Ia);
    rotate_rows01(B, R, Ia + 6);
  } else if (nd != 3 || !complete) {
    rotate_sym(A, R, Ia);
    rotate_full(B, R, Ia + 6);
  }
  rotate_sym(C, R, Ia + 15);

  // P C': p crossed with the columns of C'
  sd_real c0[3] = {C[0], C[3], C[4]}, c1[3] = {C[3], C[1], C[5]}, c2[3] = {C[4], C[5], C[2]};
  sd_real pc[3];
  sd_cross(pc, p, c0); PC[0] = pc[0]; PC[3] = pc[1]; PC[6] = pc[2];
  sd_cross(pc, p, c1); PC[1] = pc[0]; PC[4] = pc[1]; PC[7] = pc[2];
  sd_cross(pc, p, c2); PC[2] = pc[0]; PC[5] = pc[1]; PC[8] = pc[2];
  for (int k = 0; k < 9; k++) {
    M[k] = B[k] + SD_R(0.5) * PC[k];
  }
  // N = P M': column j is p x (row j of M)
  for (int j = 0; j < 3; j++) {
    sd_cross(pc, p, M + 3*j);
    N[j] = pc[0]; N[3+j] = pc[1]; N[6+j] = pc[2];
  }

  sd_real* Ap = IAp;
  sd_real* Bp = IAp + 6;
  sd_real* Cp = IAp + 15;
  for (int e = 0; e < 6; e++) {
    int i = sym_row[e], j = sym_col[e];
    Ap[e] += A[e] + N[3*i+j] + N[3*j+i];
    Cp[e] += C[e];
  }
  for (int k = 0; k < 9; k++) {
    Bp[k] += B[k] + PC[k];
  }
}

// Cholesky factor D = L L' of the symmetric positive semidefinite n x n (n <= 3, stride 3)
// matrix D, stored with the reciprocals of the diagonal. Solving with the factor keeps the
// precision an explicit inverse loses when a joint's axes are nearly parallel. At a gimbal lock
// two axes of a joint coincide and D is singular: the pivot of the later axis vanishes, and that
// dof is dropped (zero reciprocal and column, so its acceleration is 0) while the others carry
// the motion exactly. Returns the number of dofs dropped; *min_pivot gets the smallest pivot
// relative to its diagonal entry (1 for orthogonal axes, near 0 near a lock).
static int cholesky(sd_real L[9], const sd_real D[9], int n, sd_real* min_pivot) {
  int dropped = 0;
  *min_pivot = 1;
  for (int j = 0; j < n; j++) {
    sd_real diag = D[4*j];
    for (int k = 0; k < j; k++) {
      diag -= L[3*j + k] * L[3*j + k];
    }
    if (!(diag > SD_R(64) * SD_EPS * D[4*j])) {
      dropped++;
      L[4*j] = 0;
      for (int i = j + 1; i < n; i++) {
        L[3*i + j] = 0;
      }
      continue;
    }
    if (diag < *min_pivot * D[4*j]) {
      *min_pivot = diag / D[4*j];
    }
    sd_real ljj = sd_sqrt(diag);
    L[4*j] = SD_R(1) / ljj;
    for (int i = j + 1; i < n; i++) {
      sd_real s = D[3*i + j];
      for (int k = 0; k < j; k++) {
        s -= L[3*i + k] * L[3*j + k];
      }
      L[3*i + j] = s / ljj;
    }
  }
  return dropped;
}

// x = L^-1 x, the first half of a solve with the factor of cholesky()
static inline void cholesky_forward(const sd_real L[9], int n, sd_real x[3]) {
  for (int i = 0; i < n; i++) {
    for (int k = 0; k < i; k++) {
      x[i] -= L[3*i + k] * x[k];
    }
    x[i] *= L[4*i];
  }
}

// x = D^-1 x = L'^-1 L^-1 x
static inline void cholesky_solve(const sd_real L[9], int n, sd_real x[3]) {
  cholesky_forward(L, n, x);
  for (int i = n - 1; i >= 0; i--) {
    for (int k = i + 1; k < n; k++) {
      x[i] -= L[3*k + i] * x[k];
    }
    x[i] *= L[4*i];
  }
}

// One step of the inbound pass for body i, whose joint has nd dofs: project the joint out of
// the articulated inertia and bias wrench, and hand what remains to the parent. Called with a
// literal nd, so each joint size gets its own unrolled copy.
static inline void inbound_body(const sd_model* m, sd_data* d, int i, const sd_real* tau,
                                const int nd) {
  int adr = m->body_dofadr[i];
  int parent = m->body_parent[i];
  sd_real* IA = d->body_IA[i];
  sd_real* pA = d->body_pA[i];
  // U D^-1 U' = W X' and U D^-1 u = W v: W = X = U L'^-1 and v = L^-1 u (no growth of D^-1);
  // for one dof simply W = U / D, X = U, v = u
  sd_real W[3][6], X[3][6], v[3];
  int complete = 1;  // every dof projected out cleanly (well away from a gimbal lock)

  if (nd == 1) {
    // one dof about z: U = IA S is IA's third column, D = S' U its zz entry
    sd_real* U = d->dof_U[adr];
    U[0] = IA[4]; U[1] = IA[5]; U[2] = IA[2];
    U[3] = IA[12]; U[4] = IA[13]; U[5] = IA[14];
    d->dof_u[adr] = tau[adr] - pA[2];
    sd_real Dinv = 0;
    if (U[2] > 0) {
      Dinv = SD_R(1) / U[2];
    } else {
      d->warning[SD_WARN_SINGULAR]++;
    }
    d->body_L[i][0] = Dinv;
    complete = Dinv > 0;
    for (int e = 0; e < 6; e++) {
      W[0][e] = U[e] * Dinv;
      X[0][e] = U[e];
    }
    v[0] = d->dof_u[adr];
  } else if (nd > 1) {
    // U = IA S = (A z; B' z), D = S' U, u = tau - S' pA
    sd_real D[9];
    for (int k = 0; k < nd - 1; k++) {
      const sd_real* z = d->dof_axis[adr + k];
      sd_real* U = d->dof_U[adr + k];
      sd_mulsym(U, IA, z);
      sd_mulmtv(U + 3, IA + 6, z);
      d->dof_u[adr + k] = tau[adr + k] - sd_dot(z, pA);
    }
    // the last dof turns about z: its U is IA's third column
    sd_real* Uz = d->dof_U[adr + nd - 1];
    Uz[0] = IA[4]; Uz[1] = IA[5]; Uz[2] = IA[2];
    Uz[3] = IA[12]; Uz[4] = IA[13]; Uz[5] = IA[14];
    d->dof_u[adr + nd - 1] = tau[adr + nd - 1] - pA[2];
    for (int k = 0; k < nd; k++) {
      for (int l = 0; l < nd; l++) {
        D[3*k + l] = sd_dot(d->dof_axis[adr + k], d->dof_U[adr + l]);
      }
    }
    sd_real* L = d->body_L[i];
    sd_real min_pivot;
    if (cholesky(L, D, nd, &min_pivot)) {
      d->warning[SD_WARN_SINGULAR]++;
    }
    // far from a lock the projection zeroes Ia's rotational blocks to rounding; near one the
    // computed blocks carry the rounding that keeps Ia consistent with L, so they are kept
    complete = min_pivot > SD_R(1e-3);
    // W = X = U L'^-1, one row of U at a time, and v = L^-1 u
    for (int e = 0; e < 6; e++) {
      sd_real row[3];
      for (int k = 0; k < nd; k++) {
        row[k] = d->dof_U[adr + k][e];
      }
      cholesky_forward(L, nd, row);
      for (int k = 0; k < nd; k++) {
        W[k][e] = X[k][e] = row[k];
      }
    }
    for (int k = 0; k < nd; k++) {
      v[k] = d->dof_u[adr + k];
    }
    cholesky_forward(L, nd, v);
  }

  if (parent < 0) {
    return;
  }

  // in place, IA becomes Ia = IA - U D^-1 U' = IA - W X' and pA becomes
  // pa = pA + Ia c + U D^-1 u = pA + Ia c + W v
  for (int k = 0; k < nd; k++) {
    const sd_real* Wk = W[k];
    const sd_real* Xk = X[k];
    for (int e = 0; e < 6; e++) {
      IA[e] -= Wk[sym_row[e]] * Xk[sym_col[e]];
      IA[15 + e] -= Wk[3 + sym_row[e]] * Xk[3 + sym_col[e]];
    }
    for (int r = 0; r < 3; r++) {
      for (int s = 0; s < 3; s++) {
        IA[6 + 3*r + s] -= Wk[r] * Xk[3 + s];
      }
    }
  }
  const sd_real* c = d->body_c[i];
  sd_real Ac[3], Cc[3];
  sd_mulsym(Ac, IA, c);
  sd_mulsym(Cc, IA + 15, c + 3);
  for (int r = 0; r < 3; r++) {
    const sd_real* Br = IA + 6 + 3*r;
    pA[r] += Ac[r] + Br[0]*c[3] + Br[1]*c[4] + Br[2]*c[5];
    pA[3 + r] += Cc[r] + IA[6 + r]*c[0] + IA[9 + r]*c[1] + IA[12 + r]*c[2];
  }
  for (int k = 0; k < nd; k++) {
    for (int e = 0; e < 6; e++) {
      pA[e] += W[k][e] * v[k];
    }
  }

  // hand both to the parent: IA_p += X' Ia X, pA_p += X' pa = (R' n + p x R' f; R' f)
  const sd_real* R = d->body_R[i];
  add_articulated_inertia(d->body_IA[parent], IA, R, m->body_pos[i], nd, complete);
  sd_real fp[3], np[3];
  sd_mulmtv(fp, R, pA + 3);
  sd_mulmtv(np, R, pA);
  sd_addcross(np, m->body_pos[i], fp);
  sd_real* pAp = d->body_pA[parent];
  for (int k = 0; k < 3; k++) {
    pAp[k] += np[k];
    pAp[3 + k] += fp[k];
  }
}

// The body's rigid inertia [I h x; (h x)' m] as the start of its articulated inertia, and its
// bias wrench v x* (I v) - f_ext, from the velocities (w, v) already in d.
static inline void rigid_inertia_and_bias(const sd_model* m, sd_data* d, int i,
                                          const sd_real* f_ext) {
  const sd_real* w = d->body_w[i];
  const sd_real* v = d->body_v[i];
  const sd_real* h = m->body_mcom[i];
  const sd_real* I = m->body_inertia0[i];
  sd_real mass = m->body_mass[i];
  sd_real* IA = d->body_IA[i];
  for (int k = 0; k < 6; k++) {
    IA[k] = I[k];
  }
  IA[6] = 0;      IA[7] = -h[2]; IA[8] = h[1];
  IA[9] = h[2];   IA[10] = 0;    IA[11] = -h[0];
  IA[12] = -h[1]; IA[13] = h[0]; IA[14] = 0;
  IA[15] = IA[16] = IA[17] = mass;
  IA[18] = IA[19] = IA[20] = 0;

  sd_real hang[3], hlin[3];
  sd_mulsym(hang, I, w);
  sd_addcross(hang, h, v);
  sd_cross(hlin, w, h);
  sd_addtoscl3(hlin, v, mass);
  sd_real* pA = d->body_pA[i];
  sd_cross(pA, w, hang);
  sd_addcross(pA, v, hlin);
  sd_cross(pA + 3, w, hlin);
  if (f_ext) {
    for (int k = 0; k < 6; k++) {
      pA[k] -= f_ext[6*i + k];
    }
  }
}

// One step of the first outbound pass for body i with an nd-dof joint: position kinematics,
// velocities, the velocity-product acceleration c, the rigid inertia and the bias wrench.
static inline void outbound_body(const sd_model* m, sd_data* d, int i, const sd_real* q,
                                 const sd_real* qd, const sd_real* f_ext, const int nd) {
  static const sd_real zero[3] = {0, 0, 0};
  int parent = m->body_parent[i];
  const sd_real* wp = parent < 0 ? zero : d->body_w[parent];
  const sd_real* vp = parent < 0 ? zero : d->body_v[parent];
  const sd_real* p = m->body_pos[i];
  sd_real* w = d->body_w[i];
  sd_real* v = d->body_v[i];
  sd_real* c = d->body_c[i];
  sd_joint_kinematics(m, d, i, q, nd);
  const sd_real* R = d->body_R[i];

  // v = R (v_p + w_p x p); w = R w_p + sum z qd, with c_ang = sum w_(k-1) x z_k qd_k
  sd_real t[3];
  sd_cross(t, wp, p);
  sd_addto3(t, vp);
  sd_mulmv(v, R, t);
  sd_mulmv(w, R, wp);
  sd_real wjoint[3] = {0, 0, 0};
  sd_zero3(c);
  int adr = m->body_dofadr[i];
  if (nd == 3 && m->body_ball[i]) {
    // a ball joint: its dofs are the body-frame rate, so c_ang = w_parent x w_joint only
    sd_copy3(wjoint, qd + adr);
    sd_cross(c, w, wjoint);
    sd_addto3(w, wjoint);
  } else {
    for (int k = 0; k < nd; k++) {
      const sd_real* z = d->dof_axis[adr + k];
      sd_real zqd[3];
      sd_scl3(zqd, z, qd[adr + k]);
      sd_addcross(c, w, zqd);
      sd_addto3(w, zqd);
      sd_addto3(wjoint, zqd);
    }
  }
  // the joint turns about the origin, so the origin's spatial acceleration gains v x w_joint
  sd_cross(c + 3, v, wjoint);

  rigid_inertia_and_bias(m, d, i, f_ext);
}

// One step of the last outbound pass for body i with an nd-dof joint: a' = X a_p + c,
// qdd = D^-1 (u - U' a'), a = a' + S qdd.
static inline void acceleration_body(const sd_model* m, sd_data* d, int i, const sd_real* ap,
                                     sd_real* qdd, const int nd) {
  const sd_real* R = d->body_R[i];
  const sd_real* c = d->body_c[i];
  sd_real* a = d->body_a[i];

  // a' = (R dw_p; R (a_p + dw_p x p)) + c
  sd_real t[3];
  sd_cross(t, ap, m->body_pos[i]);
  sd_addto3(t, ap + 3);
  sd_mulmv(a, R, ap);
  sd_mulmv(a + 3, R, t);
  for (int k = 0; k < 6; k++) {
    a[k] += c[k];
  }
  if (nd == 0) {
    return;
  }

  int adr = m->body_dofadr[i];
  sd_real rhs[3];
  for (int k = 0; k < nd; k++) {
    const sd_real* U = d->dof_U[adr + k];
    rhs[k] = d->dof_u[adr + k] - (sd_dot(U, a) + sd_dot(U + 3, a + 3));
  }
  if (nd == 1) {
    rhs[0] *= d->body_L[i][0];
  } else {
    cholesky_solve(d->body_L[i], nd, rhs);
  }
  for (int k = 0; k < nd; k++) {
    const sd_real* z = d->dof_axis[adr + k];
    qdd[adr + k] = rhs[k];
    sd_addtoscl3(a, z, rhs[k]);
  }
}

// The free root's first outbound step: its velocity is its own 6 dofs, and c = 0 (S = 1).
static inline void free_outbound(const sd_model* m, sd_data* d, const sd_real* q,
                                 const sd_real* qd, const sd_real* f_ext) {
  sd_free_kinematics(m, d, q);
  sd_copy3(d->body_v[0], qd);
  sd_copy3(d->body_w[0], qd + 3);
  for (int k = 0; k < 6; k++) {
    d->body_c[0][k] = 0;
  }
  rigid_inertia_and_bias(m, d, 0, f_ext);
  sd_real fe[6];
  sd_root_wrench(d, fe);
  for (int k = 0; k < 6; k++) {
    d->body_pA[0][k] -= fe[k];
  }
}

// The free root's acceleration: with a' = (0; R (-g)) from the base, solve the full 6x6
// articulated inertia, IA (a - a') = tau - pA - IA a', by Cholesky.
static inline void free_acceleration(const sd_model* m, sd_data* d, const sd_real* tau,
                                     sd_real* qdd) {
  const sd_real* IA = d->body_IA[0];
  const sd_real* pA = d->body_pA[0];
  sd_real* a = d->body_a[0];
  sd_real up[3] = {-m->gravity[0], -m->gravity[1], -m->gravity[2]};
  a[0] = a[1] = a[2] = 0;
  sd_mulmv(a + 3, d->body_R[0], up);

  // the full matrix [A B; B' C] and the right-hand side (tau is force first, then moment)
  sd_real M[36], x[6];
  for (int e = 0; e < 6; e++) {
    int r = sym_row[e], c = sym_col[e];
    M[6*r + c] = M[6*c + r] = IA[e];
    M[6*(r + 3) + c + 3] = M[6*(c + 3) + r + 3] = IA[15 + e];
  }
  for (int r = 0; r < 3; r++) {
    for (int c = 0; c < 3; c++) {
      M[6*r + c + 3] = M[6*(c + 3) + r] = IA[6 + 3*r + c];
    }
  }
  for (int r = 0; r < 6; r++) {
    sd_real s = r < 3 ? tau[3 + r] - pA[r] : tau[r - 3] - pA[r];
    for (int c = 3; c < 6; c++) {
      s -= M[6*r + c] * a[c];
    }
    x[r] = s;
  }

  // Cholesky in place (lower triangle), then the two triangular solves
  for (int j = 0; j < 6; j++) {
    sd_real diag = M[7*j];
    for (int k = 0; k < j; k++) {
      diag -= M[6*j + k] * M[6*j + k];
    }
    if (!(diag > 0)) {
      d->warning[SD_WARN_SINGULAR]++;
      diag = SD_EPS;
    }
    sd_real ljj = sd_sqrt(diag);
    M[7*j] = ljj;
    for (int i = j + 1; i < 6; i++) {
      sd_real s = M[6*i + j];
      for (int k = 0; k < j; k++) {
        s -= M[6*i + k] * M[6*j + k];
      }
      M[6*i + j] = s / ljj;
    }
  }
  for (int i = 0; i < 6; i++) {
    for (int k = 0; k < i; k++) {
      x[i] -= M[6*i + k] * x[k];
    }
    x[i] /= M[7*i];
  }
  for (int i = 5; i >= 0; i--) {
    for (int k = i + 1; k < 6; k++) {
      x[i] -= M[6*k + i] * x[k];
    }
    x[i] /= M[7*i];
  }
  for (int k = 0; k < 6; k++) {
    a[k] += x[k];
  }
  for (int k = 0; k < 3; k++) {
    qdd[k] = x[3 + k];
    qdd[3 + k] = x[k];
  }
}

// dispatch on the joint size with a literal, so every size gets an unrolled copy
#define SD_BY_DOFNUM(nd, call)                         \
  switch (nd) {                                        \
    case 0: call(0); break;                            \
    case 1: call(1); break;                            \
    case 2: call(2); break;                            \
    default: call(3); break;                           \
  }

void sd_forward(const sd_model* m, sd_data* d, const sd_real* q, const sd_real* qd,
                const sd_real* tau, const sd_real* f_ext, sd_real* qdd) {
  // outbound pass: velocities, velocity-product accelerations c, rigid inertias, bias wrenches
  int first = 0;
  if (m->free_root) {
    free_outbound(m, d, q, qd, f_ext);
    first = 1;
  }
  for (int i = first; i < m->nbody; i++) {
#define SD_OUTBOUND(nd) outbound_body(m, d, i, q, qd, f_ext, nd)
    SD_BY_DOFNUM(m->body_dofnum[i], SD_OUTBOUND)
#undef SD_OUTBOUND
  }

  // inbound pass: articulated inertias and bias wrenches from the leaves to the root
  for (int i = m->nbody - 1; i >= first; i--) {
#define SD_INBOUND(nd) inbound_body(m, d, i, tau, nd)
    SD_BY_DOFNUM(m->body_dofnum[i], SD_INBOUND)
#undef SD_INBOUND
  }

  // outbound pass: accelerations from the root; the base accelerates upwards at -g
  sd_real base_acc[6] = {0, 0, 0, -m->gravity[0], -m->gravity[1], -m->gravity[2]};
  if (m->free_root) {
    free_acceleration(m, d, tau, qdd);
  }
  for (int i = first; i < m->nbody; i++) {
    int parent = m->body_parent[i];
    const sd_real* ap = parent < 0 ? base_acc : d->body_a[parent];
#define SD_ACCELERATION(nd) acceleration_body(m, d, i, ap, qdd, nd)
    SD_BY_DOFNUM(m->body_dofnum[i], SD_ACCELERATION)
#undef SD_ACCELERATION
  }

  // a non-finite input gives zero acceleration and a warning, never a NaN
  if (!sd_allfinite(qdd, m->ndof)) {
    d->warning[SD_WARN_NONFINITE]++;
    for (int j = 0; j < m->ndof; j++) {
      qdd[j] = 0;
    }
  }
}
