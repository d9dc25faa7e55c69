// ag.c: direct dynamics by the Armstrong-Green recursion (paper §3.1), in its exact O(n) form:
// an inbound pass (leaves to root) accumulates each body's articulated inertia IA and bias
// wrench pA, an outbound pass (root to leaves) yields the accelerations. Where Armstrong and Green
// assume a 3-dof joint and the paper projects with eq. 3.1, this divides by the articulated
// inertia about the joint's own free axes, D = S' IA S (at most 3x3), which is exact for 1-, 2-
// and 3-dof joints (Featherstone's articulated-body algorithm; his names: S, c, IA, pA, U, D, u).
// A dof's armature (a geared motor's rotor inertia x gear ratio^2) turns with the dof alone, so it
// adds to D's diagonal only: D = S' IA S + diag(armature), as in Pinocchio's ABA and MuJoCo.
//
// Spatial vectors are (angular; linear) at the body origin in the body frame; the transforms and
// the block storage of IA are in sd_spatial.h. Each per-body step takes its joint's dof count nd
// as a literal (see sd_forward), so every joint size gets its own unrolled copy.
#include "servodyn.h"
#include "sd_cholesky.h"
#include "sd_joint.h"
#include "sd_spatial.h"

// The body's rigid inertia as the start of its articulated inertia, and its bias wrench
// v x* (I v) - f_ext, from the velocities (w, v) already in d.
static inline void rigid_inertia_and_bias(const sd_model* m, sd_data* d, int i,
                                          const sd_real* f_ext) {
  const sd_real* w = d->body_w[i];
  const sd_real* v = d->body_v[i];
  const sd_real* h = m->body_mcom[i];
  const sd_real* I = m->body_inertia0[i];
  sd_real mass = m->body_mass[i];
  sd_ia_rigid(d->body_IA[i], mass, h, I);

  // momentum (I w + h x v; w x h + m v), then its spatial cross product with (w; v)
  sd_real hang[3], hlin[3];
  sd_mulsym(hang, I, w);
  sd_addcross(hang, h, v);
  sd_cross(hlin, w, h);
  sd_addtoscl3(hlin, v, mass);
  sd_real* pA = d->body_pA[i];
  sd_cross(pA, w, hang);
  sd_addcross(pA, v, hlin);
  sd_cross(pA + 3, w, hlin);

  // minus what the environment applies
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
  sd_real* w = d->body_w[i];
  sd_real* v = d->body_v[i];
  sd_real* c = d->body_c[i];
  int adr = m->body_dofadr[i];

  // joint transform and dof axes
  sd_joint_kinematics(m, d, i, q, nd);

  // the parent's velocity at the body origin: w = R w_p, v = R (v_p + w_p x p)
  sd_xmotion(w, v, d->body_R[i], m->body_pos[i], wp, vp);

  // plus the joint's: w += sum z qd, with c_ang = sum w_(k-1) x z_k qd_k
  sd_real wjoint[3] = {0, 0, 0};
  sd_zero3(c);
  if (nd == 3 && m->body_ball[i]) {
    // a ball joint: its dofs are the body-frame rate, so c_ang = w_parent x w_joint only
    sd_copy3(wjoint, qd + adr);
    sd_cross(c, w, wjoint);
    sd_addto3(w, wjoint);
  } else {
    for (int k = 0; k < nd; k++) {
      sd_real zqd[3];
      sd_scl3(zqd, d->dof_axis[adr + k], qd[adr + k]);
      sd_addcross(c, w, zqd);
      sd_addto3(w, zqd);
      sd_addto3(wjoint, zqd);
    }
  }

  // the joint turns about the origin, so the origin's spatial acceleration gains v x w_joint
  sd_cross(c + 3, v, wjoint);

  rigid_inertia_and_bias(m, d, i, f_ext);
}

// One step of the inbound pass for body i, whose joint has nd dofs: project the joint out of
// the articulated inertia and bias wrench, and hand what remains to the parent.
static inline void inbound_body(const sd_model* m, sd_data* d, int i, const sd_real* tau,
                                const int nd) {
  int adr = m->body_dofadr[i];
  int parent = m->body_parent[i];
  sd_real* IA = d->body_IA[i];
  sd_real* pA = d->body_pA[i];
  // U D^-1 U' = W X' and U D^-1 u = W v: W = X = U L'^-1 and v = L^-1 u (no growth of D^-1);
  // for one dof simply W = U / D, X = U, v = u
  sd_real W[3][6], X[3][6], v[3];
  int complete = 1;  // Ia S = 0: every dof projected out cleanly (well away from a gimbal lock)
  const sd_real* armature = m->dof_armature + adr;

  if (nd == 1) {
    // one dof about z: U = IA S is IA's third column, D = S' U its zz entry plus the armature
    sd_real* U = d->dof_U[adr];
    sd_ia_mulzaxis(U, IA);
    d->dof_u[adr] = tau[adr] - pA[2];
    sd_real D = U[2] + armature[0];
    sd_real Dinv = 0;
    if (D > 0) {
      Dinv = SD_R(1) / D;
    } else {
      d->warning[SD_WARN_SINGULAR]++;
    }
    d->body_L[i][0] = Dinv;
    // Ia S = 0 (or IA's z row is zero, behind a massless body), but with an armature
    // Ia S = U armature / D: then the parent takes all of Ia
    complete = armature[0] == 0;
    for (int e = 0; e < 6; e++) {
      W[0][e] = U[e] * Dinv;
      X[0][e] = U[e];
    }
    v[0] = d->dof_u[adr];
  } else if (nd > 1) {
    // U = IA S and u = tau - S' pA; the last dof turns about z, its U is IA's third column
    for (int k = 0; k < nd - 1; k++) {
      const sd_real* z = d->dof_axis[adr + k];
      sd_ia_mulaxis(d->dof_U[adr + k], IA, z);
      d->dof_u[adr + k] = tau[adr + k] - sd_dot(z, pA);
    }
    sd_ia_mulzaxis(d->dof_U[adr + nd - 1], IA);
    d->dof_u[adr + nd - 1] = tau[adr + nd - 1] - pA[2];

    // D = S' U + diag(armature) and its factor
    sd_real D[9], min_pivot;
    for (int k = 0; k < nd; k++) {
      for (int l = 0; l < nd; l++) {
        D[3*k + l] = sd_dot(d->dof_axis[adr + k], d->dof_U[adr + l]);
      }
      D[4*k] += armature[k];
    }
    sd_real* L = d->body_L[i];
    if (sd_cholesky(L, D, nd, 3, &min_pivot)) {
      d->warning[SD_WARN_SINGULAR]++;
    }
    // far from a lock the projection zeroes Ia's rotational blocks to rounding; near one the
    // computed blocks carry the rounding that keeps Ia consistent with L, so they are kept, and
    // so they are with an armature, which leaves Ia S non-zero
    complete = min_pivot > SD_R(1e-3);
    for (int k = 0; k < nd; k++) {
      complete = complete && armature[k] == 0;
    }

    // W = X = U L'^-1, one row of U at a time, and v = L^-1 u
    for (int e = 0; e < 6; e++) {
      sd_real row[3];
      for (int k = 0; k < nd; k++) {
        row[k] = d->dof_U[adr + k][e];
      }
      sd_cholesky_forward(L, nd, 3, row);
      for (int k = 0; k < nd; k++) {
        W[k][e] = X[k][e] = row[k];
      }
    }
    for (int k = 0; k < nd; k++) {
      v[k] = d->dof_u[adr + k];
    }
    sd_cholesky_forward(L, nd, 3, v);
  }

  if (parent < 0) {
    return;
  }

  // in place, IA becomes Ia = IA - U D^-1 U' = IA - W X' and pA becomes
  // pa = pA + Ia c + U D^-1 u = pA + Ia c + W v
  for (int k = 0; k < nd; k++) {
    sd_ia_subouter(IA, W[k], X[k]);
  }
  sd_ia_addtomul(pA, IA, d->body_c[i]);
  for (int k = 0; k < nd; k++) {
    for (int e = 0; e < 6; e++) {
      pA[e] += W[k][e] * v[k];
    }
  }

  // hand both to the parent: IA_p += X' Ia X, pA_p += X' pa
  const sd_real* R = d->body_R[i];
  const sd_real* p = m->body_pos[i];
  sd_ia_addto_parent(d->body_IA[parent], IA, R, p, nd, complete);
  sd_addto_xtforce(d->body_pA[parent], d->body_pA[parent] + 3, R, p, pA, pA + 3);
}

// One step of the last outbound pass for body i with an nd-dof joint: a' = X a_p + c,
// qdd = D^-1 (u - U' a'), a = a' + S qdd.
static inline void acceleration_body(const sd_model* m, sd_data* d, int i, const sd_real* ap,
                                     sd_real* qdd, const int nd) {
  const sd_real* c = d->body_c[i];
  sd_real* a = d->body_a[i];

  // a' = X a_p + c
  sd_xmotion(a, a + 3, d->body_R[i], m->body_pos[i], ap, ap + 3);
  for (int k = 0; k < 6; k++) {
    a[k] += c[k];
  }
  if (nd == 0) {
    return;
  }

  // qdd = D^-1 (u - U' a')
  int adr = m->body_dofadr[i];
  sd_real rhs[3];
  for (int k = 0; k < nd; k++) {
    const sd_real* U = d->dof_U[adr + k];
    rhs[k] = d->dof_u[adr + k] - (sd_dot(U, a) + sd_dot(U + 3, a + 3));
  }
  if (nd == 1) {
    rhs[0] *= d->body_L[i][0];
  } else {
    sd_cholesky_solve(d->body_L[i], nd, 3, rhs);
  }

  // a = a' + S qdd
  for (int k = 0; k < nd; k++) {
    qdd[adr + k] = rhs[k];
    sd_addtoscl3(a, d->dof_axis[adr + k], rhs[k]);
  }
}

// The free root's first outbound step: its velocity is its own 6 dofs, and c = 0 (S = 1).
static inline void free_outbound(const sd_model* m, sd_data* d, const sd_real* q,
                                 const sd_real* qd, const sd_real* f_ext) {
  sd_joint_kinematics(m, d, 0, q, 6);
  sd_copy3(d->body_v[0], qd);
  sd_copy3(d->body_w[0], qd + 3);
  for (int k = 0; k < 6; k++) {
    d->body_c[0][k] = 0;
  }
  rigid_inertia_and_bias(m, d, 0, f_ext);

  // minus the root force
  sd_real fe[6];
  sd_root_wrench(d, fe);
  for (int k = 0; k < 6; k++) {
    d->body_pA[0][k] -= fe[k];
  }
}

// The free root's acceleration: with a' = (0; R (-g)) from the base, solve the full 6x6
// articulated inertia, (IA + diag(armature)) (a - a') = tau - pA - IA a'.
static inline void free_acceleration(const sd_model* m, sd_data* d, const sd_real* tau,
                                     sd_real* qdd) {
  const sd_real* pA = d->body_pA[0];
  sd_real* a = d->body_a[0];
  sd_real up[3] = {-m->gravity[0], -m->gravity[1], -m->gravity[2]};
  sd_zero3(a);
  sd_mulmv(a + 3, d->body_R[0], up);

  // the right-hand side (tau is force first, then moment)
  sd_real M[36], x[6], min_pivot;
  sd_ia_full(M, d->body_IA[0]);
  for (int r = 0; r < 6; r++) {
    sd_real s = r < 3 ? tau[3 + r] - pA[r] : tau[r - 3] - pA[r];
    for (int c = 3; c < 6; c++) {
      s -= M[6*r + c] * a[c];
    }
    x[r] = s;
  }

  // the armatures turn with the dofs alone: (IA + diag(armature)) (a - a') = x
  for (int r = 0; r < 6; r++) {
    M[7*r] += m->dof_armature[r < 3 ? 3 + r : r - 3];
  }

  // a - a' = (IA + diag(armature))^-1 x, factored in place
  if (sd_cholesky(M, M, 6, 6, &min_pivot)) {
    d->warning[SD_WARN_SINGULAR]++;
  }
  sd_cholesky_solve(M, 6, 6, x);
  for (int k = 0; k < 6; k++) {
    a[k] += x[k];
  }
  sd_copy3(qdd, x + 3);
  sd_copy3(qdd + 3, x);
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
    switch (m->body_dofnum[i]) {
      case 0: outbound_body(m, d, i, q, qd, f_ext, 0); break;
      case 1: outbound_body(m, d, i, q, qd, f_ext, 1); break;
      case 2: outbound_body(m, d, i, q, qd, f_ext, 2); break;
      default: outbound_body(m, d, i, q, qd, f_ext, 3); break;
    }
  }

  // inbound pass: articulated inertias and bias wrenches from the leaves to the root
  for (int i = m->nbody - 1; i >= first; i--) {
    switch (m->body_dofnum[i]) {
      case 0: inbound_body(m, d, i, tau, 0); break;
      case 1: inbound_body(m, d, i, tau, 1); break;
      case 2: inbound_body(m, d, i, tau, 2); break;
      default: inbound_body(m, d, i, tau, 3); break;
    }
  }

  // outbound pass: accelerations from the root; the base accelerates upwards at -g
  sd_real base_acc[6] = {0, 0, 0, -m->gravity[0], -m->gravity[1], -m->gravity[2]};
  if (m->free_root) {
    free_acceleration(m, d, tau, qdd);
  }
  for (int i = first; i < m->nbody; i++) {
    int parent = m->body_parent[i];
    const sd_real* ap = parent < 0 ? base_acc : d->body_a[parent];
    switch (m->body_dofnum[i]) {
      case 0: acceleration_body(m, d, i, ap, qdd, 0); break;
      case 1: acceleration_body(m, d, i, ap, qdd, 1); break;
      case 2: acceleration_body(m, d, i, ap, qdd, 2); break;
      default: acceleration_body(m, d, i, ap, qdd, 3); break;
    }
  }

  // a non-finite input gives zero acceleration and a warning, never a NaN
  if (!sd_allfinite(qdd, m->ndof)) {
    d->warning[SD_WARN_NONFINITE]++;
    for (int j = 0; j < m->ndof; j++) {
      qdd[j] = 0;
    }
  }
}
