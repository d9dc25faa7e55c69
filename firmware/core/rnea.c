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
#include "servodyn.h"
#include "sd_joint.h"

void sd_rnea(const sd_model* m, sd_data* d, const sd_real* q, const sd_real* qd,
             const sd_real* qdd, const sd_real* f_ext, sd_real* tau) {
  static const sd_real zero[3] = {0, 0, 0};
  sd_real base_acc[3] = {-m->gravity[0], -m->gravity[1], -m->gravity[2]};

  // forward pass: velocities and accelerations from the base to the leaves
  for (int i = 0; i < m->nbody; i++) {
    int parent = m->body_parent[i];
    const sd_real* wp = parent < 0 ? zero : d->body_w[parent];
    const sd_real* dwp = parent < 0 ? zero : d->body_dw[parent];
    const sd_real* ap = parent < 0 ? base_acc : d->body_acc[parent];
    sd_real* w = d->body_w[i];
    sd_real* dw = d->body_dw[i];
    sd_real* a = d->body_acc[i];
    if (i == 0 && m->free_root) {
      // a free root: w and dw are its own dofs, and its origin's classical acceleration is the
      // free joint's (spatial) acceleration plus w x v, with the base's -g seen from the body
      sd_free_kinematics(m, d, q);
      const sd_real* v = qd;
      sd_copy3(w, qd + 3);
      sd_copy3(dw, qdd + 3);
      sd_mulmv(a, d->body_R[0], base_acc);
      sd_addto3(a, qdd);
      sd_addcross(a, w, v);
    } else {
      const sd_real* p = m->body_pos[i];
      sd_joint_kinematics(m, d, i, q, m->body_dofnum[i]);
      const sd_real* R = d->body_R[i];

      // linear acceleration of the origin: a = R (a_p + dw_p x p + w_p x (w_p x p))
      sd_real wxp[3], t[3];
      sd_cross(wxp, wp, p);
      sd_cross(t, wp, wxp);
      sd_addcross(t, dwp, p);
      sd_addto3(t, ap);
      sd_mulmv(a, R, t);

      // angular velocity and acceleration, dof by dof: dw += z qdd + w x z qd, then w += z qd
      sd_mulmv(w, R, wp);
      sd_mulmv(dw, R, dwp);
      int adr = m->body_dofadr[i];
      if (m->body_ball[i]) {
        // a ball joint's dofs are the body-frame rate itself: dw += qdd + w x qd, w += qd
        const sd_real* wj = qd + adr;
        sd_addto3(dw, qdd + adr);
        sd_addcross(dw, w, wj);
        sd_addto3(w, wj);
      } else {
        for (int j = adr; j < adr + m->body_dofnum[i]; j++) {
          const sd_real* z = d->dof_axis[j];
          sd_real zqd[3];
          sd_scl3(zqd, z, qd[j]);
          sd_addtoscl3(dw, z, qdd[j]);
          sd_addcross(dw, w, zqd);
          sd_addto3(w, zqd);
        }
      }
    }

    // the wrench that moves the body: f = m a + dw x h + w x (w x h), n = I dw + w x I w + h x a
    const sd_real* h = m->body_mcom[i];
    const sd_real* I = m->body_inertia0[i];
    sd_real mass = m->body_mass[i];
    sd_real* f = d->body_f[i];
    sd_real* n = d->body_n[i];
    sd_real wxh[3], Iw[3];
    sd_cross(wxh, w, h);
    sd_cross(f, w, wxh);
    sd_addcross(f, dw, h);
    sd_addtoscl3(f, a, mass);
    sd_mulsym(Iw, I, w);
    sd_mulsym(n, I, dw);
    sd_addcross(n, w, Iw);
    sd_addcross(n, h, a);

    // minus what the environment applies
    if (f_ext) {
      sd_subfrom3(n, f_ext + 6*i);
      sd_subfrom3(f, f_ext + 6*i + 3);
    }
    if (i == 0 && m->free_root) {
      sd_real fe[6];
      sd_root_wrench(d, fe);
      sd_subfrom3(n, fe);
      sd_subfrom3(f, fe + 3);
    }
  }

  // backward pass: joint torques from the leaves, each body's wrench passed to its parent
  for (int i = m->nbody - 1; i >= 0; i--) {
    const sd_real* f = d->body_f[i];
    const sd_real* n = d->body_n[i];
    int adr = m->body_dofadr[i];
    if (i == 0 && m->free_root) {
      // the free root's generalized force is its whole wrench: force, then moment
      sd_copy3(tau, f);
      sd_copy3(tau + 3, n);
      continue;
    }
    for (int j = adr; j < adr + m->body_dofnum[i]; j++) {
      tau[j] = sd_dot(n, d->dof_axis[j]);
    }
    int parent = m->body_parent[i];
    if (parent >= 0) {
      // f_p += R' f, n_p += R' n + p x R' f
      const sd_real* R = d->body_R[i];
      sd_real fp[3], np[3];
      sd_mulmtv(fp, R, f);
      sd_mulmtv(np, R, n);
      sd_addcross(np, m->body_pos[i], fp);
      sd_addto3(d->body_f[parent], fp);
      sd_addto3(d->body_n[parent], np);
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
