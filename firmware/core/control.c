// control.c: the closed-form controller step (paper Fig. 4): inverse dynamics every time_step,
// a joint PD every small_time_step, torque limits counted as limiting, bad numbers as faults.
#include <stddef.h>

#include "servodyn.h"
#include "sd_math.h"

int sd_control_check(const sd_model* m, const sd_control_config* c) {
  // the mode and the update period
  if (c->mode < 0 || c->mode >= SD_NMODE) {
    return SD_CONTROL_ERR_MODE;
  }
  if (c->update_ticks < 1) {
    return SD_CONTROL_ERR_UPDATE;
  }

  // the joint PD works on angles: ball joints (quaternions) are for simulation only
  for (int i = 0; i < m->nbody; i++) {
    if (m->body_ball[i]) {
      return SD_CONTROL_ERR_BALL;
    }
  }

  // gains and limits: zero or positive, and finite
  for (int j = 0; j < m->ndof; j++) {
    if (!(c->kp[j] >= 0) || !(c->kd[j] >= 0) || !SD_ISFINITE(c->kp[j]) || !SD_ISFINITE(c->kd[j])) {
      return SD_CONTROL_ERR_GAIN;
    }
    if (!(c->tau_max[j] >= 0) || !SD_ISFINITE(c->tau_max[j])) {
      return SD_CONTROL_ERR_LIMIT;
    }
    if (!(c->error_lowpass[j] >= 0 && c->error_lowpass[j] <= 1)) {
      return SD_CONTROL_ERR_FILTER;
    }
    if (!(c->friction_coulomb[j] >= 0) || !SD_ISFINITE(c->friction_coulomb[j]) ||
        !(c->friction_viscous[j] >= 0) || !SD_ISFINITE(c->friction_viscous[j]) ||
        (c->friction_coulomb[j] > 0 && !(c->friction_speed > 0 && SD_ISFINITE(c->friction_speed)))) {
      return SD_CONTROL_ERR_FRICTION;
    }
  }
  return SD_CONTROL_OK;
}

const char* sd_control_strerror(int code) {
  switch (code) {
    case SD_CONTROL_OK:         return "ok";
    case SD_CONTROL_ERR_MODE:   return "mode unknown";
    case SD_CONTROL_ERR_UPDATE: return "update_ticks < 1";
    case SD_CONTROL_ERR_BALL:   return "a ball joint: the joint PD works on angles";
    case SD_CONTROL_ERR_GAIN:   return "a gain (kp or kd) negative or not finite";
    case SD_CONTROL_ERR_LIMIT:  return "a torque limit negative or not finite";
    case SD_CONTROL_ERR_FILTER: return "an error low-pass coefficient outside [0, 1]";
    case SD_CONTROL_ERR_FRICTION:
      return "a friction negative or not finite, or Coulomb friction without a positive friction_speed";
    default:                    return "unknown error";
  }
}

void sd_control_reset(sd_control_state* s) {
  s->tick = 0;
  s->status = 0;
  s->refresh = 0;
  s->nlimited = 0;
  s->nfault = 0;
  s->filtered = 0;
  for (int j = 0; j < SD_MAX_DOF; j++) {
    s->tau_hold[j] = 0;
    s->e[j] = 0;
    s->de[j] = 0;
  }
}

// every small step: the tracking errors of every dof (position through its coordinate in q),
// low-passed where error_lowpass says: a one-pole filter started at the first measured errors
static void filter_errors(const sd_model* m, const sd_control_config* c, sd_control_state* s,
                          const sd_real* q_d, const sd_real* qd_d, const sd_real* q, const sd_real* qd) {
  for (int i = m->free_root ? 1 : 0; i < m->nbody; i++) {
    for (int k = 0; k < m->body_dofnum[i]; k++) {
      int qi = m->body_qadr[i] + k, vi = m->body_dofadr[i] + k;
      sd_real e = q_d[qi] - q[qi], de = qd_d[vi] - qd[vi];
      sd_real a = c->error_lowpass[vi];
      if (s->filtered && a > 0) {
        s->e[vi] += a * (e - s->e[vi]);
        s->de[vi] += a * (de - s->de[vi]);
      } else {
        s->e[vi] = e;
        s->de[vi] = de;
      }
    }
  }
  s->filtered = 1;
}

// a faulty step: no torque at all, the fault flagged and counted
static void refuse(sd_control_state* s, int nv, sd_real* tau, int status) {
  for (int j = 0; j < nv; j++) {
    tau[j] = 0;
  }
  s->status = status;
  s->nfault++;
  s->tick++;
  s->refresh = 1;  // a skipped update must not leave an old torque held for a whole period
  s->filtered = 0; // nor an overflowed error in the low-pass
}

void sd_control_step(const sd_model* m, sd_data* d, const sd_control_config* c,
                     sd_control_state* s, const sd_real* q_d, const sd_real* qd_d,
                     const sd_real* qdd_d, const sd_real* q, const sd_real* qd, sd_real* tau) {
  int nv = m->ndof, first = m->free_root ? 1 : 0;
  s->status = 0;

  // a non-finite input is a fault: no torque at all, never a NaN
  if (!sd_allfinite(q_d, m->nq) || !sd_allfinite(qd_d, nv) || !sd_allfinite(qdd_d, nv) ||
      !sd_allfinite(q, m->nq) || !sd_allfinite(qd, nv)) {
    refuse(s, nv, tau, SD_STATUS_NONFINITE);
    return;
  }
  int warned = d->warning[SD_WARN_NONFINITE];
  filter_errors(m, c, s, q_d, qd_d, q, qd);

  // every time_step, and after a fault: the inverse dynamics, held until the next update
  if (s->tick % c->update_ticks == 0 || s->refresh) {
    s->refresh = 0;
    if (c->mode == SD_MODE_FEEDFORWARD || c->mode == SD_MODE_FEEDFORWARD_PD) {
      sd_rnea(m, d, q_d, qd_d, qdd_d, NULL, s->tau_hold);
    } else if (c->mode == SD_MODE_COMPUTED_TORQUE) {
      // the reference acceleration qdd_d + kp e + kd e' at the measured state
      for (int j = 0; j < nv; j++) {
        s->qdd_ref[j] = qdd_d[j];
      }
      for (int i = first; i < m->nbody; i++) {
        for (int k = 0; k < m->body_dofnum[i]; k++) {
          int vi = m->body_dofadr[i] + k;
          s->qdd_ref[vi] += c->kp[vi] * s->e[vi] + c->kd[vi] * s->de[vi];
        }
      }
      sd_rnea(m, d, q, qd, s->qdd_ref, NULL, s->tau_hold);
    } else {
      for (int j = 0; j < nv; j++) {
        s->tau_hold[j] = 0;
      }
    }
  }
  for (int j = 0; j < nv; j++) {
    tau[j] = s->tau_hold[j];
  }

  // every small step: friction compensation on the desired velocity. The Coulomb step is
  // smoothed, tanh(qd_d / friction_speed): a plan that reverses a joint would otherwise step the
  // command by 2 F_c in one tick (a knock at every reversal), and at rest the sign of a speed a
  // few encoder counts wide is noise; a compensation on the desired (not the measured) velocity
  // adds no feedback, so it cannot make the loop chatter
  if (c->mode != SD_MODE_PD) {
    for (int j = 0; j < nv; j++) {
      tau[j] += sd_friction(c->friction_coulomb[j], c->friction_viscous[j], c->friction_speed, qd_d[j]);
    }
  }

  // every small step: the joint PD on top of the held torque
  if (c->mode == SD_MODE_FEEDFORWARD_PD || c->mode == SD_MODE_PD) {
    for (int i = first; i < m->nbody; i++) {
      for (int k = 0; k < m->body_dofnum[i]; k++) {
        int vi = m->body_dofadr[i] + k;
        tau[vi] += c->kp[vi] * s->e[vi] + c->kd[vi] * s->de[vi];
      }
    }
  }

  // finite inputs whose torque is not (the inverse dynamics zeroed an overflow and counted it,
  // or the PD overflowed) are a fault too: a zero or clamped torque would be silently wrong
  if (d->warning[SD_WARN_NONFINITE] != warned || !sd_allfinite(tau, nv)) {
    refuse(s, nv, tau, SD_STATUS_OVERFLOW);
    return;
  }

  // a free root is not actuated; the limits clamp and are counted as limiting, not as faults
  for (int j = 0; j < (m->free_root ? 6 : 0); j++) {
    tau[j] = 0;
  }
  for (int j = 0; j < nv; j++) {
    sd_real limit = c->tau_max[j];
    if (limit > 0 && (tau[j] > limit || tau[j] < -limit)) {
      tau[j] = tau[j] > 0 ? limit : -limit;
      s->status |= SD_STATUS_LIMITED;
    }
  }
  if (s->status & SD_STATUS_LIMITED) {
    s->nlimited++;
  }
  s->tick++;
}
