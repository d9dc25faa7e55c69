// integrate.c: fixed-step integration of (q, qd) with the direct dynamics (paper §3.1).
// RK4 evaluates the inbound/outbound recursion four times per step; explicit Euler once.
#include "servodyn.h"
#include "sd_math.h"

void sd_step(const sd_model* m, sd_data* d, sd_real* q, sd_real* qd, const sd_real* tau,
             const sd_real* f_ext, sd_real dt, int integrator) {
  int n = m->ndof;
  sd_real* qdd = d->step_qdd;

  // explicit Euler: both updates from the state at the start of the step
  if (integrator == SD_EULER) {
    sd_forward(m, d, q, qd, tau, f_ext, qdd);
    for (int j = 0; j < n; j++) {
      q[j] += dt * qd[j];
      qd[j] += dt * qdd[j];
    }
    return;
  }

  // classical RK4: slopes k1..k4 at t, t+dt/2, t+dt/2, t+dt, summed with weights 1 2 2 1
  static const sd_real stage_dt[3] = {SD_R(0.5), SD_R(0.5), SD_R(1)};
  static const sd_real weight[4] = {SD_R(1), SD_R(2), SD_R(2), SD_R(1)};
  sd_real* qs = d->step_q;
  sd_real* qds = d->step_qd;
  sd_real* kq = d->step_kq;
  sd_real* kqd = d->step_kqd;
  for (int j = 0; j < n; j++) {
    qs[j] = q[j];
    qds[j] = qd[j];
    kq[j] = 0;
    kqd[j] = 0;
  }
  for (int stage = 0; stage < 4; stage++) {
    sd_forward(m, d, qs, qds, tau, f_ext, qdd);
    sd_real w = weight[stage];
    for (int j = 0; j < n; j++) {
      kq[j] += w * qds[j];
      kqd[j] += w * qdd[j];
    }
    // the next stage's state: the start plus a fraction of this stage's slope
    if (stage < 3) {
      sd_real h = stage_dt[stage] * dt;
      for (int j = 0; j < n; j++) {
        sd_real slope_q = qds[j];
        qs[j] = q[j] + h * slope_q;
        qds[j] = qd[j] + h * qdd[j];
      }
    }
  }
  sd_real sixth = dt / SD_R(6);
  for (int j = 0; j < n; j++) {
    q[j] += sixth * kq[j];
    qd[j] += sixth * kqd[j];
  }
}
