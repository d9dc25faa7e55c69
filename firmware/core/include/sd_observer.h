// sd_observer.h (public): the generalized-momentum observer (De Luca & Mattone 2005; Haddadin,
// De Luca, Albu-Schaeffer, IEEE T-RO 2017) that turns the joint torques, positions and velocities
// read each tick into an estimate of the external torque: the residual r, a first-order low-pass
// copy of it per joint, r_j(s) = k_j / (s + k_j) tau_ext,j(s), that needs no acceleration.
//
//   M(q) qdd + C(q, qd) qd + g(q) + tau_f(qd) = tau_m + tau_ext,   M' = C + C'
//   p = M qd,   dp/dt = tau_m - tau_f - beta + tau_ext,   beta = g - C' qd
//
// sd_momentum computes p, g and C' qd in one O(n) pass (no differencing): p_i = S_i' h_i and
// (C' qd)_i = dT/dq_i = -S_i' (v_i x* h_i), h_i the momentum of the subtree below dof i and v_i
// the velocity of the frame the dof's axis is fixed in. The armature adds armature qd to p and
// nothing to C' qd. Configuration and state are separate structs, as for the controller.
#ifndef SD_OBSERVER_H
#define SD_OBSERVER_H

#include "sd_config.h"

#ifdef __cplusplus
extern "C" {
#endif

struct sd_model_;
struct sd_data_;

// The momentum terms at (q (nq), qd (ndof)): p = M(q) qd, g = g(q) (the torques that hold the
// arm still against gravity) and ctqd = C(q, qd)' qd, each (ndof); beta = g - ctqd. Root forces
// (sd_data.root_force) are not in g: the observer sees them as external. Leaves in d: body_R,
// dof_axis, body_w, body_v, body_acc (gravity's), body_n, body_f (the static wrench from the
// parent, as sd_rnea(q, 0, 0) leaves them) and body_hn, body_hf (the subtree momentum).
void sd_momentum(const struct sd_model_* m, struct sd_data_* d, const sd_real* q,
                 const sd_real* qd, sd_real* p, sd_real* g, sd_real* ctqd);

typedef struct sd_observer_config_ {
  sd_real dt;                             // s: the sample period, > 0
  sd_real gain[SD_MAX_DOF];               // (ndof) K_O, 1/s: the residual's bandwidth, >= 0
                                          //   (0: the dof is not observed, r stays 0)
  // friction the model explains, subtracted from the motor torque: as the controller's
  // compensation, F_c tanh(qd / friction_speed) + F_v qd, on the measured velocity
  sd_real friction_coulomb[SD_MAX_DOF];   // (ndof) N m; 0 for none
  sd_real friction_viscous[SD_MAX_DOF];   // (ndof) N m s/rad; 0 for none
  sd_real friction_speed;                 // rad/s: > 0 where any friction_coulomb is
  // a one-pole low-pass on r, rad/s (0: none): the velocity's quantum reaches r unfiltered, as
  // gain M(q) dqd, while the external torque comes through gain/(s + gain) already; filtering r
  // at w_f then averages that noise over ~1/w_f and delays a step by about 1/w_f
  sd_real lowpass[SD_MAX_DOF];            // (ndof) rad/s, >= 0
} sd_observer_config;

typedef struct sd_observer_state_ {
  long tick;                      // samples taken since sd_observer_reset
  sd_real decay[SD_MAX_DOF];      // (ndof) exp(-gain dt), set by sd_observer_reset
  sd_real p[SD_MAX_DOF];          // (ndof) momentum M(q) qd at the last sample
  sd_real explained[SD_MAX_DOF];  // (ndof) beta + friction at the last sample
  sd_real r[SD_MAX_DOF];          // (ndof) the residual, N m: the external torque through
                                  //   gain/(s + gain)
  sd_real rf[SD_MAX_DOF];         // (ndof) r through the low-pass (r itself where lowpass is 0):
                                  //   what a detection compares with its thresholds
  sd_real lowpass_decay[SD_MAX_DOF];  // (ndof) exp(-lowpass dt) (0 without a low-pass), set by
                                      //   sd_observer_reset
  sd_real g[SD_MAX_DOF];          // (ndof) scratch: g(q) of the last sample
  sd_real ctqd[SD_MAX_DOF];       // (ndof) scratch: C' qd of the last sample
  int status;                     // 0, or SD_OBSERVER_NONFINITE: the last sample was refused
  long nfault;                    // samples refused since sd_observer_reset
} sd_observer_state;

enum sd_observer_status_ {
  SD_OBSERVER_NONFINITE = 1,      // a non-finite input or momentum: the sample was skipped, r kept
};

enum sd_observer_error_ {
  SD_OBSERVER_OK = 0,
  SD_OBSERVER_ERR_PERIOD = -1,    // dt not positive and finite
  SD_OBSERVER_ERR_GAIN = -2,      // a gain negative or not finite
  SD_OBSERVER_ERR_FRICTION = -3,  // a friction negative or not finite, or Coulomb friction
                                  // without a positive finite friction_speed
  SD_OBSERVER_ERR_LOWPASS = -4,   // a low-pass negative or not finite
};

// Check a configuration against a model: SD_OBSERVER_OK or the first fault's negative code.
int sd_observer_check(const struct sd_model_* m, const sd_observer_config* c);

// A short static description of an sd_observer_check code.
const char* sd_observer_strerror(int code);

// Start (or restart, after torque off or a re-enable) at the measured state: r = 0, the
// momentum and the model's explanation taken at (q, qd). One sd_momentum.
void sd_observer_reset(const struct sd_model_* m, struct sd_data_* d, const sd_observer_config* c,
                       sd_observer_state* s, const sd_real* q, const sd_real* qd);

// One sample: the measured (q, qd) and the motor torque tau_m (ndof, N m at the joint) that
// acted over the period ending now. The residual is the exact discretization of the first-order
// filter with the period's mean external torque held:
//   r <- decay r + (1 - decay) [ (p - p_prev) / dt - tau_m + (b + b_prev) / 2 ],
// b = beta + friction (trapezoidal over the period), then rf <- e rf + (1 - e) r with
// e = exp(-lowpass dt). One sd_momentum; s->r and s->rf hold the result.
// A non-finite input skips the sample (status SD_OBSERVER_NONFINITE, r and p unchanged).
void sd_observer_step(const struct sd_model_* m, struct sd_data_* d, const sd_observer_config* c,
                      sd_observer_state* s, const sd_real* q, const sd_real* qd,
                      const sd_real* tau_m);

#ifdef __cplusplus
}
#endif

#endif  // SD_OBSERVER_H
