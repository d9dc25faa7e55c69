// sd_trajectory.h (public): keyframe trajectories of the servodyn core, twice continuously
// differentiable.
//
// A trajectory is nknot keyframes, each a time and ndof positions. sd_trajectory_setup() gives
// every keyframe a velocity and an acceleration taken from the cubic spline through the
// keyframes with zero end velocities, then sets the first and last accelerations to zero. Each
// segment between two keyframes is the quintic polynomial matching position, velocity and
// acceleration at both of its keyframes, so the curve
//   - passes through every keyframe and is C2 (position, velocity, acceleration continuous);
//   - equals the clamped cubic spline on the inner segments (all but the first and the last);
//   - starts and ends at rest: zero velocity and acceleration at the first and last keyframe;
//   - holds the first keyframe before its time and the last keyframe after its time.
// Like the rest of the core it allocates nothing, prints nothing, and its loops are bounded by
// the compile-time limits.
#ifndef SD_TRAJECTORY_H
#define SD_TRAJECTORY_H

#include "sd_config.h"

#ifdef __cplusplus
extern "C" {
#endif

// Largest number of keyframes a trajectory holds; an MCU build may set a smaller limit with -D.
#ifndef SD_MAX_KNOT
#define SD_MAX_KNOT 64
#endif

// A keyframe trajectory: the caller fills nknot, ndof, knot_t and knot_q, and
// sd_trajectory_setup() computes the rest.
typedef struct sd_trajectory_ {
  int nknot;                                  // number of keyframes, 2..SD_MAX_KNOT
  int ndof;                                   // dofs per keyframe, 1..SD_MAX_DOF
  sd_real knot_t[SD_MAX_KNOT];                // (nknot) strictly increasing times (s)
  sd_real knot_q[SD_MAX_KNOT][SD_MAX_DOF];    // (nknot x ndof) positions

  // derived by sd_trajectory_setup
  sd_real knot_qd[SD_MAX_KNOT][SD_MAX_DOF];   // (nknot x ndof) velocities at the keyframes
  sd_real knot_qdd[SD_MAX_KNOT][SD_MAX_DOF];  // (nknot x ndof) accelerations at the keyframes
} sd_trajectory;

// Error codes of sd_trajectory_setup; 0 (SD_OK of servodyn.h) means accepted.
enum sd_trajectory_error_ {
  SD_ERR_KNOTS = -20,        // nknot outside 2..SD_MAX_KNOT or ndof outside 1..SD_MAX_DOF
  SD_ERR_TIME = -21,         // a keyframe time not finite, not after the previous one, or so
                             //   close to it that 1 / gap^2 overflows
  SD_ERR_KNOTVALUE = -22,    // a NaN or infinite keyframe position
  SD_ERR_SPLINE = -23,       // a derived velocity or acceleration overflows: positions too
                             //   large for the spacing of the keyframes
};

// Validate a trajectory filled in by the caller and compute its keyframe velocities and
// accelerations. Returns 0 (SD_OK) or a negative sd_trajectory_error_ code; *bad_knot and
// *bad_dof receive the offending keyframe and dof, or -1 when the error names none (either
// pointer may be NULL). On an error the derived fields are unspecified.
int sd_trajectory_setup(sd_trajectory* tr, int* bad_knot, int* bad_dof);

// Evaluate a trajectory accepted by sd_trajectory_setup() at time t: position q, velocity qd and
// acceleration qdd (ndof each; any of the three may be NULL). Before the first keyframe (and for
// a NaN t) the first keyframe is held, after the last keyframe the last one is held, both with
// zero velocity and acceleration. Costs a binary search over the keyframes and one quintic per dof.
void sd_trajectory_eval(const sd_trajectory* tr, sd_real t, sd_real* q, sd_real* qd,
                        sd_real* qdd);

// One segment's quintic, the one sd_trajectory_eval plays between two keyframes: through
// (t0, q0, qd0, qdd0) and (t1, q1, qd1, qdd1), ndof dofs each, t0 < t1, evaluated at t (in
// [t0, t1]; any of q, qd, qdd may be NULL). A controller fed keyframes one at a time (the host
// link's knots) plays them through this.
void sd_trajectory_segment(int ndof, sd_real t0, sd_real t1, const sd_real* q0, const sd_real* qd0,
                           const sd_real* qdd0, const sd_real* q1, const sd_real* qd1, const sd_real* qdd1,
                           sd_real t, sd_real* q, sd_real* qd, sd_real* qdd);

// A short static description of an sd_trajectory_setup() error code.
const char* sd_trajectory_strerror(int code);

#ifdef __cplusplus
}
#endif

#endif  // SD_TRAJECTORY_H
