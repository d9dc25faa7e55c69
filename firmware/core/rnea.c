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
// (sd_joint_kinematics) and its motion below; a free root is the joint of 6 dofs. A dof's
// armature (a geared motor's rotor) adds armature qdd to its torque, as in Pinocchio and MuJoCo.
#include "servodyn.h"
#include "sd_joint.h"
#include "sd_spatial.h"

// Add the motion of body i's nd-dof joint to the motion w, dw, a it inherits from its parent.
static inline void joint_motion(const sd_model* m, const sd_data* d, int i, const int nd,
                                const sd_real* qd, const sd_real* qdd, sd_real* w, sd_real* dw,
                                sd_real* a) {
  int adr = m->body_dofadr[i];

  // a ball joint, or a free root's rotation: the dofs are the body-frame rate itself,
  // dw += qdd + w x qd, w += qd
  if (nd == 6 || m->body_ball[i]) {
    int rot = nd == 6 ? adr + 3 : adr;
    sd_addto3(dw, qdd + rot);
    sd_addcross(dw, w, qd + rot);
    sd_addto3(w, qd + rot);

    // a free root's translation: its origin accelerates by qdd_lin + w x v
    if (nd == 6) {
      sd_addto3(a, qdd + adr);
      sd_addcross(a, w, qd + adr);
    }
    return;
  }

  // hinges, dof by dof: dw += z qdd + w x z qd, then w += z qd
  for (int j = adr; j < adr + nd; j++) {
    const sd_real* z = d->dof_axis[j];
    sd_real zqd[3];
    sd_scl3(zqd, z, qd[j]);
    sd_addtoscl3(dw, z, qdd[j]);
    sd_addcross(dw, w, zqd);
    sd_addto3(w, zqd);
  }
}

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
  static const sd_real zero[3] = {0, 0, 0};
  sd_real base_acc[3] = {-m->gravity[0], -m->gravity[1], -m->gravity[2]};

  // forward pass: velocities and accelerations from the base to the leaves
  for (int i = 0; i < m->nbody; i++) {
    int parent = m->body_parent[i], nd = m->body_dofnum[i];
    const sd_real* wp = parent < 0 ? zero : d->body_w[parent];
    const sd_real* dwp = parent < 0 ? zero : d->body_dw[parent];
    const sd_real* ap = parent < 0 ? base_acc : d->body_acc[parent];
    const sd_real* p = m->body_pos[i];
    sd_real* w = d->body_w[i];
    sd_real* dw = d->body_dw[i];
    sd_real* a = d->body_acc[i];

    // joint transform and dof axes
    sd_joint_kinematics(m, d, i, q, nd);
    const sd_real* R = d->body_R[i];

    // the parent's motion at the body origin: w = R w_p, dw = R dw_p and
    // a = R (a_p + dw_p x p + w_p x (w_p x p))
    sd_real wxp[3], t[3];
    sd_cross(wxp, wp, p);
    sd_cross(t, wp, wxp);
    sd_addcross(t, dwp, p);
    sd_addto3(t, ap);
    sd_mulmv(a, R, t);
    sd_mulmv(w, R, wp);
    sd_mulmv(dw, R, dwp);

    // plus the joint's own
    joint_motion(m, d, i, nd, qd, qdd, w, dw, a);

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
