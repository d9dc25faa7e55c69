// sd_control.h (public): the closed-form controller step (paper §3.2, Fig. 4).
//
// Every small_time_step the controller turns the desired state and the measured state into
// joint torques; every time_step (an integer multiple, ~10 in the paper) it recomputes the
// inverse dynamics and holds the result (zero-order) in between. The same step runs on the
// host, in the simulated servos' tests and in the firmware. Configuration, state and the
// commands it writes are separate structs (moteus' config / status / command split).
#ifndef SD_CONTROL_H
#define SD_CONTROL_H

#include "sd_config.h"

#ifdef __cplusplus
extern "C" {
#endif

struct sd_model_;
struct sd_data_;

enum sd_control_mode_ {
  SD_MODE_FEEDFORWARD = 0,      // tau = RNEA(q_d, qd_d, qdd_d), held for time_step
  SD_MODE_FEEDFORWARD_PD = 1,   // the held feed-forward plus kp e + kd e' every small step
  SD_MODE_COMPUTED_TORQUE = 2,  // tau = RNEA(q, qd, qdd_d + kp e + kd e'), held for time_step
  SD_MODE_PD = 3,               // kp e + kd e' alone, every small step
  SD_NMODE
};

// Status bits of the last step: limiting is normal operation, a fault is not.
enum sd_control_status_ {
  SD_STATUS_LIMITED = 1,        // at least one torque was clamped to its limit
  SD_STATUS_NONFINITE = 2,      // a non-finite input: every torque set to zero (fault)
  SD_STATUS_OVERFLOW = 4,       // finite inputs, a non-finite torque (the inverse dynamics or the
                                // PD overflowed): every torque set to zero (fault)
};

typedef struct sd_control_config_ {
  int mode;                       // an sd_control_mode_
  int update_ticks;               // time_step / small_time_step: small steps per inverse dynamics
  sd_real kp[SD_MAX_DOF];         // (ndof) N m/rad, or 1/s^2 in computed-torque mode
  sd_real kd[SD_MAX_DOF];         // (ndof) N m s/rad, or 1/s in computed-torque mode
  sd_real tau_max[SD_MAX_DOF];    // (ndof) |tau| limit (N m); 0 for none
  sd_real error_lowpass[SD_MAX_DOF];  // (ndof) one-pole low-pass on the errors the gains act on,
                                  // 1 - exp(-w_c small_time_step) in [0, 1]; 0 for none. The
                                  // measured state is quantised (an encoder tick, a velocity
                                  // unit): this keeps the gains from buzzing at that resolution
  // friction compensated on the desired velocity, every small step, in every mode but PD:
  // F_c tanh(qd_d / friction_speed) + F_v qd_d (the Coulomb step smoothed, see control.c)
  sd_real friction_coulomb[SD_MAX_DOF];   // (ndof) N m; 0 for none
  sd_real friction_viscous[SD_MAX_DOF];   // (ndof) N m s/rad; 0 for none
  sd_real friction_speed;                 // rad/s: > 0 where any friction_coulomb is
} sd_control_config;

typedef struct sd_control_state_ {
  long tick;                      // small steps taken since sd_control_reset
  sd_real tau_hold[SD_MAX_DOF];   // (ndof) the torque of the last inverse dynamics, held
  sd_real qdd_ref[SD_MAX_DOF];    // (ndof) scratch: reference acceleration of computed torque
  sd_real e[SD_MAX_DOF];          // (ndof) position error q_d - q, low-passed (error_lowpass)
  sd_real de[SD_MAX_DOF];         // (ndof) velocity error qd_d - qd, low-passed
  int filtered;                   // 0: the next step starts the low-pass at the measured errors
  int status;                     // sd_control_status_ bits of the last step
  int refresh;                    // 1: recompute the inverse dynamics at the next good step
  long nlimited;                  // steps with a clamped torque
  long nfault;                    // steps refused: non-finite input or result
} sd_control_state;

// Error codes of sd_control_check.
enum sd_control_error_ {
  SD_CONTROL_OK = 0,
  SD_CONTROL_ERR_MODE = -1,       // mode outside the sd_control_mode_ values
  SD_CONTROL_ERR_UPDATE = -2,     // update_ticks < 1
  SD_CONTROL_ERR_BALL = -3,       // the model has a ball joint: the joint PD works on angles
  SD_CONTROL_ERR_GAIN = -4,       // a kp or kd negative or not finite
  SD_CONTROL_ERR_LIMIT = -5,      // a torque limit negative or not finite
  SD_CONTROL_ERR_FILTER = -6,     // an error_lowpass outside [0, 1]
  SD_CONTROL_ERR_FRICTION = -7,   // a friction negative or not finite, or Coulomb's without a
                                  // positive finite friction_speed
};

// Check a configuration against a model: SD_CONTROL_OK or the negative sd_control_error_ code of
// the first fault found (mode, update period, ball joints, then each dof's gains, limit and
// friction).
int sd_control_check(const struct sd_model_* m, const sd_control_config* c);

// A short static description of an sd_control_check code.
const char* sd_control_strerror(int code);

// Start a run: tick 0, nothing held, counters cleared.
void sd_control_reset(sd_control_state* s);

// One small step: from the desired (q_d, qd_d, qdd_d) and measured (q, qd) state, the torques
// tau (ndof). Inverse dynamics run on ticks that are multiples of update_ticks. The gains act on
// the tracking errors through their low-pass (error_lowpass): the desired motion is the
// prediction and the measurement corrects it, so the filter's lag falls on the error alone. A free root is
// not actuated: its six torques are always zero, and its coordinates carry no error. A step
// whose inputs or torques are not finite gives zero torque and a fault (SD_STATUS_NONFINITE,
// SD_STATUS_OVERFLOW), never a NaN nor an overflow zeroed or clamped into a plausible number.
void sd_control_step(const struct sd_model_* m, struct sd_data_* d, const sd_control_config* c,
                     sd_control_state* s, const sd_real* q_d, const sd_real* qd_d,
                     const sd_real* qdd_d, const sd_real* q, const sd_real* qd, sd_real* tau);

#ifdef __cplusplus
}
#endif

#endif  // SD_CONTROL_H
