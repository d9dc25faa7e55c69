// integrate.c: fixed-step integration of (q, qd) with the direct dynamics (paper §3.1).
// RK4 evaluates the inbound/outbound recursion four times per step; explicit Euler once.
// Unit quaternions (a free root, ball joints) are integrated as four numbers and renormalized,
// which keeps the orientation a rotation without lowering the order of the method.
#include "servodyn.h"
#include "sd_joint.h"

// quatdot = quat (x) (w, 0) / 2 for a quaternion (x, y, z, s) turning at the body-frame rate w
static inline void quat_rate(const sd_real* quat, const sd_real* w, sd_real* rate) {
  sd_real x = quat[0], y = quat[1], z = quat[2], s = quat[3];
  rate[0] = SD_R(0.5) * (s*w[0] + y*w[2] - z*w[1]);
  rate[1] = SD_R(0.5) * (s*w[1] + z*w[0] - x*w[2]);
  rate[2] = SD_R(0.5) * (s*w[2] + x*w[1] - y*w[0]);
  rate[3] = SD_R(-0.5) * (x*w[0] + y*w[1] + z*w[2]);
}

static inline void normalize4(sd_real* quat) {
  sd_real norm = sd_sqrt(quat[0]*quat[0] + quat[1]*quat[1] + quat[2]*quat[2] + quat[3]*quat[3]);
  if (norm > 0) {
    for (int k = 0; k < 4; k++) {
      quat[k] /= norm;
    }
  }
}

void sd_position_rate(const sd_model* m, const sd_real* q, const sd_real* qd, sd_real* qdot) {
  int first = 0;
  if (m->free_root) {
    // the origin moves at world_R_body v; the quaternion turns at the body-frame rate
    sd_real Rw[9];
    sd_quat_to_rot(Rw, q + 3);
    sd_mulmv(qdot, Rw, qd);
    quat_rate(q + 3, qd + 3, qdot + 3);
    first = 1;
  }
  for (int i = first; i < m->nbody; i++) {
    int qadr = m->body_qadr[i], adr = m->body_dofadr[i];
    if (m->body_ball[i]) {
      quat_rate(q + qadr, qd + adr, qdot + qadr);
      continue;
    }
    // hinge coordinates move at their own rates
    for (int k = 0; k < m->body_dofnum[i]; k++) {
      qdot[qadr + k] = qd[adr + k];
    }
  }
}

void sd_normalize_q(const sd_model* m, sd_real* q) {
  if (m->free_root) {
    normalize4(q + 3);
  }
  for (int i = 0; i < m->nbody; i++) {
    if (m->body_ball[i]) {
      normalize4(q + m->body_qadr[i]);
    }
  }
}

void sd_step(const sd_model* m, sd_data* d, sd_real* q, sd_real* qd, const sd_real* tau,
             const sd_real* f_ext, sd_real dt, int integrator) {
  int nq = m->nq, nv = m->ndof;
  sd_real* qdd = d->step_qdd;
  sd_real* qdot = d->step_qdot;

  // explicit Euler: both updates from the state at the start of the step
  if (integrator == SD_EULER) {
    sd_forward(m, d, q, qd, tau, f_ext, qdd);
    sd_position_rate(m, q, qd, qdot);
    for (int j = 0; j < nq; j++) {
      q[j] += dt * qdot[j];
    }
    for (int j = 0; j < nv; j++) {
      qd[j] += dt * qdd[j];
    }
    sd_normalize_q(m, q);
    return;
  }

  // classical RK4: slopes k1..k4 at t, t+dt/2, t+dt/2, t+dt, summed with weights 1 2 2 1
  static const sd_real stage_dt[3] = {SD_R(0.5), SD_R(0.5), SD_R(1)};
  static const sd_real weight[4] = {SD_R(1), SD_R(2), SD_R(2), SD_R(1)};
  sd_real* qs = d->step_q;
  sd_real* qds = d->step_qd;
  sd_real* kq = d->step_kq;
  sd_real* kqd = d->step_kqd;
  for (int j = 0; j < nq; j++) {
    qs[j] = q[j];
    kq[j] = 0;
  }
  for (int j = 0; j < nv; j++) {
    qds[j] = qd[j];
    kqd[j] = 0;
  }
  for (int stage = 0; stage < 4; stage++) {
    sd_forward(m, d, qs, qds, tau, f_ext, qdd);
    sd_position_rate(m, qs, qds, qdot);
    sd_real w = weight[stage];
    for (int j = 0; j < nq; j++) {
      kq[j] += w * qdot[j];
    }
    for (int j = 0; j < nv; j++) {
      kqd[j] += w * qdd[j];
    }
    // the next stage's state: the start plus a fraction of this stage's slope
    if (stage < 3) {
      sd_real h = stage_dt[stage] * dt;
      for (int j = 0; j < nq; j++) {
        qs[j] = q[j] + h * qdot[j];
      }
      for (int j = 0; j < nv; j++) {
        qds[j] = qd[j] + h * qdd[j];
      }
    }
  }
  sd_real sixth = dt / SD_R(6);
  for (int j = 0; j < nq; j++) {
    q[j] += sixth * kq[j];
  }
  for (int j = 0; j < nv; j++) {
    qd[j] += sixth * kqd[j];
  }
  sd_normalize_q(m, q);
}
