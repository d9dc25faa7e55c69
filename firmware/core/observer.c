// observer.c: the generalized-momentum observer (sd_observer.h) and the momentum terms it needs,
// p = M qd, g and C' qd, in one recursion over the tree.
//
// Forward pass, as sd_rnea's with qdd = 0: each body's angular velocity w, origin velocity v and
// the gravity it feels (the base's upward acceleration -g, rotated; no velocity terms), then its
// momentum about its origin (n; f) = (I0 w + h x v; m v + w x h) and its static wrench
// (h x a_g; m a_g). Backward pass: both summed over the subtree, carried to the parent as sd_rnea
// carries forces, and projected on each dof:
//   p_k = z_k . n^C + armature_k qd_k,   g_k = z_k . n_g^C,
//   (C' qd)_k = -z_k . (w_k x n^C + v x f^C)
// with w_k the angular velocity of the frame dof k's axis is fixed in: the parent's plus the
// joint's dofs up to k (the dofs after k turn that frame's successors, not it; dof k's own term
// drops out since z x z = 0). A ball joint's axes and a free root's are fixed in the body: w_k is
// the body's. A free root's six dofs are (force; moment) of -(v x* h), Pinocchio's free-flyer.
#include "servodyn.h"
#include "sd_joint.h"
#include "sd_spatial.h"

void sd_momentum(const sd_model* m, sd_data* d, const sd_real* q, const sd_real* qd,
                 sd_real* p, sd_real* g, sd_real* ctqd) {
  static const sd_real zero[3] = {0, 0, 0};
  const sd_real base_acc[3] = {-m->gravity[0], -m->gravity[1], -m->gravity[2]};

  // forward pass: velocities, gravity, each body's own momentum and static wrench
  for (int i = 0; i < m->nbody; i++) {
    int nd = m->body_dofnum[i], parent = m->body_parent[i], adr = m->body_dofadr[i];
    const sd_real* wp = parent < 0 ? zero : d->body_w[parent];
    const sd_real* vp = parent < 0 ? zero : d->body_v[parent];
    const sd_real* ap = parent < 0 ? base_acc : d->body_acc[parent];
    sd_joint_kinematics(m, d, i, q, nd);
    const sd_real* R = d->body_R[i];
    sd_real* w = d->body_w[i];
    sd_real* v = d->body_v[i];
    sd_real* a = d->body_acc[i];

    // the parent's motion at the body origin: v = R (v_p + w_p x pos), w = R w_p; gravity rotated
    sd_real t[3];
    sd_cross(t, wp, m->body_pos[i]);
    sd_addto3(t, vp);
    sd_mulmv(v, R, t);
    sd_mulmv(w, R, wp);
    sd_mulmv(a, R, ap);

    // plus the joint's own velocity
    if (nd == 6) {
      sd_addto3(v, qd + adr);
      sd_addto3(w, qd + adr + 3);
    } else if (m->body_ball[i]) {
      sd_addto3(w, qd + adr);
    } else {
      for (int j = adr; j < adr + nd; j++) {
        sd_addtoscl3(w, d->dof_axis[j], qd[j]);
      }
    }

    // momentum about the origin: hf = m v + w x h, hn = I0 w + h x v
    const sd_real* h = m->body_mcom[i];
    sd_real* hn = d->body_hn[i];
    sd_real* hf = d->body_hf[i];
    sd_scl3(hf, v, m->body_mass[i]);
    sd_addcross(hf, w, h);
    sd_mulsym(hn, m->body_inertia0[i], w);
    sd_addcross(hn, h, v);

    // the static wrench that holds the body against gravity: f = m a_g, n = h x a_g
    sd_scl3(d->body_f[i], a, m->body_mass[i]);
    sd_cross(d->body_n[i], h, a);
  }

  // backward pass: subtree sums, projected on each dof, then handed to the parent
  for (int i = m->nbody - 1; i >= 0; i--) {
    int nd = m->body_dofnum[i], adr = m->body_dofadr[i], parent = m->body_parent[i];
    const sd_real* hn = d->body_hn[i];
    const sd_real* hf = d->body_hf[i];
    const sd_real* v = d->body_v[i];
    sd_real t[3];
    if (nd == 6) {
      // the whole momentum and wrench, force first; -(v x* h) = -(w x f; w x n + v x f)
      sd_cross(t, d->body_w[i], hf);
      for (int r = 0; r < 3; r++) {
        p[adr + r] = hf[r];
        g[adr + r] = d->body_f[i][r];
        ctqd[adr + r] = -t[r];
      }
      sd_cross(t, d->body_w[i], hn);
      sd_addcross(t, v, hf);
      for (int r = 0; r < 3; r++) {
        p[adr + 3 + r] = hn[r];
        g[adr + 3 + r] = d->body_n[i][r];
        ctqd[adr + 3 + r] = -t[r];
      }
    } else {
      // t = w_k x n^C + v x f^C, w_k stepping down from the body's w one dof at a time
      sd_real wk[3];
      sd_copy3(wk, d->body_w[i]);
      for (int j = adr + nd - 1; j >= adr; j--) {
        const sd_real* z = d->dof_axis[j];
        sd_cross(t, wk, hn);
        sd_addcross(t, v, hf);
        p[j] = sd_dot(z, hn);
        g[j] = sd_dot(z, d->body_n[i]);
        ctqd[j] = -sd_dot(z, t);
        if (!m->body_ball[i]) {
          sd_addtoscl3(wk, z, -qd[j]);
        }
      }
    }
    for (int j = adr; j < adr + nd; j++) {
      p[j] += m->dof_armature[j] * qd[j];
    }
    if (parent >= 0) {
      sd_addto_xtforce(d->body_hn[parent], d->body_hf[parent], d->body_R[i], m->body_pos[i], hn, hf);
      sd_addto_xtforce(d->body_n[parent], d->body_f[parent], d->body_R[i], m->body_pos[i],
                       d->body_n[i], d->body_f[i]);
    }
  }
}

//---------------------------------- the observer ------------------------------------------------

int sd_observer_check(const sd_model* m, const sd_observer_config* c) {
  if (!(c->dt > 0) || !SD_ISFINITE(c->dt)) {
    return SD_OBSERVER_ERR_PERIOD;
  }
  for (int j = 0; j < m->ndof; j++) {
    if (!(c->gain[j] >= 0) || !SD_ISFINITE(c->gain[j])) {
      return SD_OBSERVER_ERR_GAIN;
    }
    if (!(c->friction_coulomb[j] >= 0) || !SD_ISFINITE(c->friction_coulomb[j]) ||
        !(c->friction_viscous[j] >= 0) || !SD_ISFINITE(c->friction_viscous[j]) ||
        (c->friction_coulomb[j] > 0 && !(c->friction_speed > 0 && SD_ISFINITE(c->friction_speed)))) {
      return SD_OBSERVER_ERR_FRICTION;
    }
    if (!(c->lowpass[j] >= 0) || !SD_ISFINITE(c->lowpass[j])) {
      return SD_OBSERVER_ERR_LOWPASS;
    }
  }
  return SD_OBSERVER_OK;
}

const char* sd_observer_strerror(int code) {
  switch (code) {
    case SD_OBSERVER_OK:         return "ok";
    case SD_OBSERVER_ERR_PERIOD: return "the sample period is not positive and finite";
    case SD_OBSERVER_ERR_GAIN:   return "a gain negative or not finite";
    case SD_OBSERVER_ERR_FRICTION:
      return "a friction negative or not finite, or Coulomb friction without a positive friction_speed";
    case SD_OBSERVER_ERR_LOWPASS: return "a low-pass negative or not finite";
    default:                     return "unknown error";
  }
}

// p = M qd and what the model explains of its rate, beta + friction, at (q, qd); 0 when the
// result is not finite
static int sample(const sd_model* m, sd_data* d, const sd_observer_config* c, sd_observer_state* s,
                  const sd_real* q, const sd_real* qd, sd_real* p, sd_real* explained) {
  sd_momentum(m, d, q, qd, p, s->g, s->ctqd);
  for (int j = 0; j < m->ndof; j++) {
    explained[j] = s->g[j] - s->ctqd[j] +
                   sd_friction(c->friction_coulomb[j], c->friction_viscous[j], c->friction_speed, qd[j]);
  }
  return sd_allfinite(p, m->ndof) && sd_allfinite(explained, m->ndof);
}

void sd_observer_reset(const sd_model* m, sd_data* d, const sd_observer_config* c,
                       sd_observer_state* s, const sd_real* q, const sd_real* qd) {
  s->tick = 0;
  s->status = 0;
  s->nfault = 0;
  for (int j = 0; j < m->ndof; j++) {
    s->decay[j] = sd_exp(-c->gain[j] * c->dt);
    // no low-pass: rf = r
    s->lowpass_decay[j] = c->lowpass[j] > 0 ? sd_exp(-c->lowpass[j] * c->dt) : SD_R(0);
    s->r[j] = 0;
    s->rf[j] = 0;
  }
  if (!(sd_allfinite(q, m->nq) && sd_allfinite(qd, m->ndof) &&
        sample(m, d, c, s, q, qd, s->p, s->explained))) {
    // nothing to start from: the first good sample starts the observer
    s->status = SD_OBSERVER_NONFINITE;
    s->nfault++;
    s->tick = -1;
  }
}

void sd_observer_step(const sd_model* m, sd_data* d, const sd_observer_config* c,
                      sd_observer_state* s, const sd_real* q, const sd_real* qd,
                      const sd_real* tau_m) {
  sd_real p[SD_MAX_DOF], explained[SD_MAX_DOF];
  if (!(sd_allfinite(q, m->nq) && sd_allfinite(qd, m->ndof) && sd_allfinite(tau_m, m->ndof) &&
        sample(m, d, c, s, q, qd, p, explained))) {
    s->status = SD_OBSERVER_NONFINITE;
    s->nfault++;
    return;
  }
  s->status = 0;
  if (s->tick < 0) {
    // started on a refused state: this is the first sample
    s->tick = 0;
  } else {
    const sd_real half = SD_R(0.5), inv_dt = SD_R(1) / c->dt;
    for (int j = 0; j < m->ndof; j++) {
      sd_real tau_ext = (p[j] - s->p[j]) * inv_dt - tau_m[j] + half * (explained[j] + s->explained[j]);
      s->r[j] = s->decay[j] * s->r[j] + (SD_R(1) - s->decay[j]) * tau_ext;
      s->rf[j] = s->lowpass_decay[j] * s->rf[j] + (SD_R(1) - s->lowpass_decay[j]) * s->r[j];
    }
    s->tick++;
  }
  for (int j = 0; j < m->ndof; j++) {
    s->p[j] = p[j];
    s->explained[j] = explained[j];
  }
}
