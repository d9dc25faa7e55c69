// rnea.c: inverse dynamics by the recursive Newton-Euler algorithm (paper Appendix, after Luh,
// Walker and Paul), exact for joints of 1 to 3 dofs.
//
// Names follow the paper: w (omega), dw (alpha), a (linear acceleration of the body origin),
// f and n (force and moment on body i from its parent), tau, p (joint origin in the parent), z
// (dof axes). Two departures from Table 2, both needed for exactness:
//   - the angular acceleration carries the coupling of successive dofs of one joint: each dof's
//     axis turns with the dofs before it, alpha += w_(k-1) x z_k qd_k, not only w_parent x (...);
//   - every quantity is taken about the body origin with the first moment h = m s, so gravity is
//     the base's upward acceleration -g and needs no per-body term g_i.
// Every joint goes through the same two steps, as with spatial_v2's jcalc: its kinematics
// (sd_joint_kinematics) and its motion (sd_body_motion, shared with sd_regressor); a free root is the joint of 6 dofs. A dof's
// armature (a geared motor's rotor) adds armature qdd to its torque, as in Pinocchio and MuJoCo.
#include "servodyn.h"
#include "sd_joint.h"
#include "sd_spatial.h"

// The generalized force of body i's nd-dof joint from the wrench (n, f) the body receives,
// plus what accelerates each dof's armature: armature qdd.
static inline void joint_force(const sd_model* m, const sd_data* d, int i, const int nd,
                               const sd_real* n, const sd_real* f, const sd_real* qdd,
                               sd_real* tau) {
  int adr = m->body_dofadr[i];

  // a free root: its whole wrench, force first, then moment
  if (nd == 6) {
    sd_copy3(tau + adr, f);
    sd_copy3(tau + adr + 3, n);
  } else {
    // a hinge or ball joint: the moment about each dof axis
    for (int j = adr; j < adr + nd; j++) {
      tau[j] = sd_dot(n, d->dof_axis[j]);
    }
  }
  for (int j = adr; j < adr + nd; j++) {
    tau[j] += m->dof_armature[j] * qdd[j];
  }
}

void sd_rnea(const sd_model* m, sd_data* d, const sd_real* q, const sd_real* qd,
             const sd_real* qdd, const sd_real* f_ext, sd_real* tau) {
  // forward pass: velocities and accelerations from the base to the leaves
  for (int i = 0; i < m->nbody; i++) {
    int nd = m->body_dofnum[i];
    sd_body_motion(m, d, i, q, qd, qdd, nd);
    const sd_real* w = d->body_w[i];
    const sd_real* dw = d->body_dw[i];
    const sd_real* a = d->body_acc[i];

    // the wrench that moves the body: f = m a + dw x h + w x (w x h), n = I dw + w x I w + h x a
    const sd_real* h = m->body_mcom[i];
    const sd_real* I = m->body_inertia0[i];
    sd_real* f = d->body_f[i];
    sd_real* n = d->body_n[i];
    sd_real wxh[3], Iw[3];
    sd_cross(wxh, w, h);
    sd_cross(f, w, wxh);
    sd_addcross(f, dw, h);
    sd_addtoscl3(f, a, m->body_mass[i]);
    sd_mulsym(Iw, I, w);
    sd_mulsym(n, I, dw);
    sd_addcross(n, w, Iw);
    sd_addcross(n, h, a);

    // minus what the environment applies
    if (f_ext) {
      sd_subfrom3(n, f_ext + 6*i);
      sd_subfrom3(f, f_ext + 6*i + 3);
    }
    if (nd == 6) {
      sd_real fe[6];
      sd_root_wrench(d, fe);
      sd_subfrom3(n, fe);
      sd_subfrom3(f, fe + 3);
    }
  }

  // backward pass: joint torques from the leaves, each body's wrench passed to its parent
  for (int i = m->nbody - 1; i >= 0; i--) {
    int parent = m->body_parent[i];
    joint_force(m, d, i, m->body_dofnum[i], d->body_n[i], d->body_f[i], qdd, tau);
    if (parent >= 0) {
      sd_addto_xtforce(d->body_n[parent], d->body_f[parent], d->body_R[i], m->body_pos[i],
                       d->body_n[i], d->body_f[i]);
    }
  }

  // a non-finite input gives zero torque and a warning, never a NaN torque
  if (!sd_allfinite(tau, m->ndof)) {
    d->warning[SD_WARN_NONFINITE]++;
    for (int j = 0; j < m->ndof; j++) {
      tau[j] = 0;
    }
  }
}
