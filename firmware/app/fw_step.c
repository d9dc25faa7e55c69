// fw_step.c: the controller step of one tick, the same in both applications (fw_app.h): the
// momentum observer (sd_observer.h), the core's controller (sd_control.h: inverse dynamics every
// update_ticks, held, plus the PD and friction), the guards and the servo command.
#include "fw_app.h"

#define FW_RANGE_MARGIN SD_R(0.35)     // rad beyond a joint's range that is taken for a fault

const char* fw_fault_name(int code) {
  switch (code) {
    case FW_OK: return "none";
    case FW_FAULT_TIMEOUT: return "timeout";
    case FW_FAULT_STATUS: return "status";
    case FW_FAULT_CORRUPT: return "corrupt";
    case FW_FAULT_NONFINITE: return "nonfinite";
    case FW_FAULT_OVERRUN: return "overrun";
    case FW_FAULT_RANGE: return "range";
    case FW_FAULT_SETUP: return "setup";
    case FW_FAULT_OVERFLOW: return "overflow";
    case FW_FAULT_CONTACT: return "contact";
    case FW_FAULT_FOLLOWING_ERROR: return "following_error";
    case FW_FAULT_STALL: return "stall";
    default: return "unknown";
  }
}

void fw_step_init(fw_step* s, const sd_model* model, const fw_servo* servo, int njoint, const fw_guards* guards,
                  sd_real dt, sd_real friction_speed) {
  s->model = model;
  s->servo = servo;
  s->guards = guards;
  s->njoint = njoint;
  s->fault_servo = s->contact_servo = s->fault_joint = -1;
  s->fault_value = 0;
  s->control.friction_speed = friction_speed;
  s->oconfig.dt = dt;
  s->oconfig.friction_speed = friction_speed;
  for (int i = 0; i < njoint; i++) {
    s->control.friction_coulomb[i] = servo[i].friction_coulomb;
    s->control.friction_viscous[i] = servo[i].friction_viscous;
    s->oconfig.gain[i] = servo[i].observer_gain;
    s->oconfig.lowpass[i] = servo[i].observer_lowpass;
    s->oconfig.friction_coulomb[i] = servo[i].friction_coulomb;
    s->oconfig.friction_viscous[i] = servo[i].friction_viscous;
  }
}

// joint limits: a desired position outside the range is clamped to it (limiting)
int fw_step_clamp_plan(const fw_step* s, sd_real* q_d, sd_real* qd_d, sd_real* qdd_d) {
  int limited = 0;
  for (int i = 0; i < s->njoint; i++) {
    const fw_servo* v = &s->servo[i];
    if (q_d[i] < v->q_min || q_d[i] > v->q_max) {
      q_d[i] = q_d[i] < v->q_min ? v->q_min : v->q_max;
      qd_d[i] = qdd_d[i] = 0;
      limited = 1;
    }
  }
  return limited;
}

// Start the observer at the measured state (r = 0; its exponentials taken), at the read that
// begins a run: outside the ticks, so the first tick pays one sample as every other does.
void fw_step_start(fw_step* s, const sd_real* q, const sd_real* qd) {
  sd_observer_reset(s->model, &s->data, &s->oconfig, &s->observer, q, qd);
  for (int i = 0; i < s->njoint; i++) s->over[i] = 0, s->pressed[i] = 0;
}

// The observer's sample of this tick (stepped as ContactObserver.update is).
void fw_step_observe(fw_step* s, const sd_real* q, const sd_real* qd, const sd_real* current) {
  for (int i = 0; i < s->njoint; i++) s->tau_measured[i] = s->servo[i].nm_per_amp * current[i];
  sd_observer_step(s->model, &s->data, &s->oconfig, &s->observer, q, qd, s->tau_measured);
}

int fw_step_control(fw_step* s, const sd_real* q_d, const sd_real* qd_d, const sd_real* qdd_d, const sd_real* q,
                    const sd_real* qd) {
  sd_control_step(s->model, &s->data, &s->control, &s->cstate, q_d, qd_d, qdd_d, q, qd, s->tau);
  if (s->cstate.status & SD_STATUS_NONFINITE) return FW_FAULT_NONFINITE;
  if (s->cstate.status & SD_STATUS_OVERFLOW) return FW_FAULT_OVERFLOW;
  return FW_OK;
}

// a measured joint far outside its range is a sensor or mechanical fault, not a command
static int check_range(fw_step* s, const sd_real* q) {
  for (int i = 0; i < s->njoint; i++) {
    const fw_servo* v = &s->servo[i];
    if (!(q[i] > v->q_min - FW_RANGE_MARGIN && q[i] < v->q_max + FW_RANGE_MARGIN)) {
      s->fault_servo = v->id, s->fault_joint = i;
      return FW_FAULT_RANGE;
    }
  }
  return FW_OK;
}

// the guards (host/loop/safety.py's, on the same table): a joint further from its command than its
// following-error limit; a joint commanded at its torque limit that does not move, stall_ticks long
static int check_guards(fw_step* s, const sd_real* q_d, const sd_real* q, const sd_real* qd) {
  const fw_guards* g = s->guards;
  for (int i = 0; i < s->njoint; i++) {
    const fw_servo* v = &s->servo[i];
    sd_real error = q_d[i] - q[i];
    if (error > v->following_error || error < -v->following_error) {
      s->fault_servo = v->id, s->fault_joint = i;
      s->fault_value = error < 0 ? -error : error;
      return FW_FAULT_FOLLOWING_ERROR;
    }
    sd_real limit = g->stall_share * v->current_limit * v->nm_per_amp;
    sd_real tau = s->tau[i];
    int pressed = (tau >= limit || tau <= -limit) && qd[i] < g->stall_speed && qd[i] > -g->stall_speed;
    s->pressed[i] = pressed ? s->pressed[i] + 1 : 0;
    if (s->pressed[i] >= g->stall_ticks) {
      s->fault_servo = v->id, s->fault_joint = i;
      s->fault_value = tau < 0 ? -tau : tau;
      return FW_FAULT_STALL;
    }
  }
  return FW_OK;
}

// The contact rule: joint i is over when |rf_i| > its threshold; a contact once any joint has been
// over contact_debounce ticks in a row and the observer has run contact_arm_ticks ticks. The first
// such joint is the fault's servo; the last joint over its threshold names the link (a contact's
// force reaches only the joints between the base and it).
static int check_contact(fw_step* s) {
  const fw_guards* g = s->guards;
  if (!g->contact) return FW_OK;
  int found = -1, last = -1;
  for (int i = 0; i < s->njoint; i++) {
    sd_real r = s->observer.rf[i];
    int over = r > s->servo[i].contact_threshold || r < -s->servo[i].contact_threshold;
    s->over[i] = over ? s->over[i] + 1 : 0;
    if (over) last = i;
    if (found < 0 && s->over[i] >= g->contact_debounce) found = i;
  }
  // ContactObserver's clock: t - t0 = the samples stepped since the reset (its tick) periods
  if (found < 0 || s->observer.tick < g->contact_arm_ticks) return FW_OK;
  sd_real r = s->observer.rf[found];
  s->fault_servo = s->servo[found].id, s->fault_joint = found;
  s->fault_value = r < 0 ? -r : r;
  s->contact_servo = s->servo[last].id;
  return FW_FAULT_CONTACT;
}

// joint torque -> servo command units, clamped at each servo's current limit (limiting); a CAN
// motor's command is its bus's (the MIT frame's torque field, fw_can_write)
static int output(fw_step* s) {
  int limited = 0;
  for (int i = 0; i < s->njoint; i++) {
    const fw_servo* v = &s->servo[i];
    if (v->can) continue;
    sd_real amps = s->tau[i] / v->nm_per_amp;
    if (amps > v->current_limit || amps < -v->current_limit) {
      amps = amps > 0 ? v->current_limit : -v->current_limit;
      limited = 1;
    }
    sd_real units = v->direction * amps / v->amp_per_unit;
    s->goal[i] = (int16_t)(units < 0 ? units - SD_R(0.5) : units + SD_R(0.5));
  }
  return limited;
}

int fw_step_finish(fw_step* s, const sd_real* q_d, const sd_real* q, const sd_real* qd, int* limited) {
  int err = check_range(s, q);
  if (err == FW_OK) err = check_guards(s, q_d, q, qd);
  if (err == FW_OK) err = check_contact(s);
  if (err) return err;
  *limited |= output(s);
  *limited |= (s->cstate.status & SD_STATUS_LIMITED) != 0;
  return FW_OK;
}

// where a board records each tick (the native loop's log); none on a microcontroller
__attribute__((weak)) void fw_record_tick(long tick, int njoint, const sd_real* q_d, const sd_real* q,
                                          const sd_real* qd, const sd_real* tau, const sd_real* current) {
  (void)tick, (void)njoint, (void)q_d, (void)q, (void)qd, (void)tau, (void)current;
}
