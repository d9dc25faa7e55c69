// servodyn.h (public): the API of the servodyn dynamics core.
//
// The public headers are the ones in firmware/core/include, the only core folder on the include
// path of the binding, the firmware and the tests; the helpers beside the sources (sd_math.h,
// sd_spatial.h, sd_cholesky.h, sd_joint.h) are internal to the core and may change freely.
//
// The model (sd_model) is constant once sd_model_setup() has accepted it; everything that
// changes each step lives in sd_data. Every function takes (const sd_model*, sd_data*, ...),
// allocates nothing, prints nothing and never fails: bad numbers are counted in d->warning[].
//
// Conventions (paper §2, Fig. 3):
//   - bodies are numbered so that a parent comes before its children; parent -1 is the fixed base;
//   - each body hangs from its parent by one joint of 0 to 3 rotational dofs; dof k of a joint
//     rotates about the z axis of its own dof frame; the dof frames of a joint share one origin,
//     body_pos in the parent frame, which is also the origin of the body frame;
//   - a 3-dof joint may instead be a ball joint (body_ball = 1): its coordinates are a unit
//     quaternion (x, y, z, w) of the body in its joint frame, 4 numbers of q, and its 3 dofs the
//     body's angular velocity relative to the parent, in the body frame; no gimbal lock;
//   - or body 0 floats freely, the paper's FREE node (free_root = 1): 6 dofs whose coordinates are
//     the origin in the base frame and a unit quaternion (x, y, z, w), 7 numbers of q; its
//     velocity is (v, w) of the origin in the body frame, its "torque" the wrench (f, n) in the
//     body frame: the order and frames of Pinocchio's free-flyer;
//   - the body frame is the last dof frame after its rotation (the joint frame for a 0-dof joint);
//   - rotations are row-major 3x3, R[3*row + col]; a_R_b maps b-frame coordinates to a-frame ones;
//   - a spatial vector is (angular; linear), a wrench is (torque about the body origin; force),
//     both in the body frame;
//   - SI units: metres, kilograms, seconds, radians, newtons, newton-metres.
#ifndef SERVODYN_H
#define SERVODYN_H

#include "sd_config.h"

#ifdef __cplusplus
extern "C" {
#endif

//---------------------------------- model -------------------------------------------------------

typedef struct sd_model_ {
  int nbody;                              // number of moving bodies
  int ndof;                               // number of degrees of freedom (length of qd, tau)
  int free_root;                          // 1: body 0 floats freely with 6 dofs; 0: all hinged
  sd_real gravity[3];                     // gravitational acceleration, base frame (m/s^2)

  // tree and joints
  int body_parent[SD_MAX_BODY];           // (nbody) parent body id; -1 for the fixed base
  int body_dofnum[SD_MAX_BODY];           // (nbody) dofs of the body's joint, 0..3
  int body_dofadr[SD_MAX_BODY];           // (nbody) index in qd of the joint's first dof
  int body_ball[SD_MAX_BODY];             // (nbody) 1: a ball joint of 3 dofs (quaternion in q)
  sd_real body_pos[SD_MAX_BODY][3];       // (nbody x 3) joint origin in the parent frame
  sd_real body_rot[SD_MAX_BODY][9];       // (nbody x 9) parent_R_frame of the joint's first frame
  sd_real dof_rot[SD_MAX_DOF][9];         // (ndof x 9) prev_R_dof: dof frame in the previous dof's
                                          //   rotated frame; identity for a joint's first dof

  // inertia
  sd_real body_mass[SD_MAX_BODY];         // (nbody) mass (kg)
  sd_real body_com[SD_MAX_BODY][3];       // (nbody x 3) centre of mass in the body frame (m)
  sd_real body_inertia[SD_MAX_BODY][6];   // (nbody x 6) inertia about the com, body frame:
                                          //   xx yy zz xy xz yz (kg m^2)
  sd_real dof_armature[SD_MAX_DOF];       // (ndof) armature: inertia that turns with the dof alone,
                                          //   a geared motor's rotor inertia x gear ratio^2 (kg m^2),
                                          //   added to the joint-space inertia's diagonal; >= 0

  // derived by sd_model_setup
  int nq;                                 // length of q: ndof, plus 1 per quaternion (free
                                          //   root, ball joints)
  int body_qadr[SD_MAX_BODY];             // (nbody) index in q of the joint's first coordinate
  sd_real body_mcom[SD_MAX_BODY][3];      // (nbody x 3) mass * com, the first moment h
  sd_real body_inertia0[SD_MAX_BODY][6];  // (nbody x 6) inertia about the body origin
  sd_real body_rotT[SD_MAX_BODY][9];      // (nbody x 9) frame_R_parent, transpose of body_rot
  sd_real dof_rotT[SD_MAX_DOF][9];        // (ndof x 9) transpose of dof_rot
  int body_ident[SD_MAX_BODY];            // (nbody) 1 when the joint needs no fixed rotation
} sd_model;

// Error codes of sd_model_setup.
enum sd_error_ {
  SD_OK = 0,
  SD_ERR_SIZE = -1,          // nbody or ndof outside 1..SD_MAX_BODY / 0..SD_MAX_DOF
  SD_ERR_PARENT = -2,        // parent not in -1..i-1
  SD_ERR_DOFNUM = -3,        // dofs of a joint outside 0..3, or dof addresses not consecutive
  SD_ERR_NONFINITE = -4,     // a NaN or infinite number in the model
  SD_ERR_ROTATION = -5,      // a fixed rotation that is not orthonormal with determinant +1
  SD_ERR_MASS = -6,          // mass not positive
  SD_ERR_INERTIA = -7,       // inertia not positive definite or violating the triangle inequality
  SD_ERR_FIRSTDOF = -8,      // dof_rot of a joint's first dof is not the identity
  SD_ERR_FREE = -9,          // a free root that is not body 0 on the base with 6 dofs
  SD_ERR_BALL = -10,         // a ball joint without exactly 3 dofs
  SD_ERR_ARMATURE = -11,     // an armature negative, NaN or infinite
};

// Validate a model filled in by the caller and compute its derived fields.
// Returns SD_OK or a negative sd_error_ code; *bad_body receives the offending body (or -1).
int sd_model_setup(sd_model* m, int* bad_body);

// A short static description of an error code.
const char* sd_strerror(int code);

// Mass, com and inertia about the com of solid primitives with their axis along local z.
// Each returns 0, or -1 when a dimension is not positive.
int sd_inertia_cylinder(sd_real mass, sd_real radius, sd_real length, sd_real inertia[6]);
int sd_inertia_sphere(sd_real mass, sd_real radius, sd_real inertia[6]);
int sd_inertia_ellipsoid(sd_real mass, sd_real a, sd_real b, sd_real c, sd_real inertia[6]);
// frustum (truncated cone) from z=0 (radius r0) to z=length (radius r1); com_z gets its centroid
int sd_inertia_frustum(sd_real mass, sd_real r0, sd_real r1, sd_real length,
                       sd_real* com_z, sd_real inertia[6]);

//---------------------------------- data --------------------------------------------------------

// Warning counters: events the math met and survived.
enum sd_warning_ {
  SD_WARN_NONFINITE = 0,     // a non-finite result (from a non-finite input); output set to 0
  SD_WARN_SINGULAR,          // a joint at a gimbal lock (or massless): a redundant dof got qdd = 0
  SD_NWARNING
};

typedef struct sd_data_ {
  // computed by the kinematics of sd_rnea and sd_forward
  sd_real body_R[SD_MAX_BODY][9];         // (nbody x 9) body_R_parent
  sd_real dof_axis[SD_MAX_DOF][3];        // (ndof x 3) dof rotation axis z in the body frame
  sd_real body_w[SD_MAX_BODY][3];         // (nbody x 3) angular velocity, body frame
  sd_real body_v[SD_MAX_BODY][3];         // (nbody x 3) velocity of the body origin (sd_forward)

  // computed by sd_rnea: accelerations and the wrench each body receives from its parent
  sd_real body_dw[SD_MAX_BODY][3];        // (nbody x 3) angular acceleration
  sd_real body_acc[SD_MAX_BODY][3];       // (nbody x 3) linear acceleration of the origin
  sd_real body_n[SD_MAX_BODY][3];         // (nbody x 3) torque n_i about the origin
  sd_real body_f[SD_MAX_BODY][3];         // (nbody x 3) force f_i

  // computed by sd_momentum (sd_observer.h): the momentum of the subtree from each body on, about
  // the body origin, body frame
  sd_real body_hn[SD_MAX_BODY][3];        // (nbody x 3) angular momentum
  sd_real body_hf[SD_MAX_BODY][3];        // (nbody x 3) linear momentum

  // computed by sd_forward (articulated-body terms, Featherstone's names)
  sd_real body_c[SD_MAX_BODY][6];         // (nbody x 6) velocity-product acceleration
  sd_real body_IA[SD_MAX_BODY][21];       // (nbody x 21) articulated inertia: A(6) B(9) C(6)
  sd_real body_pA[SD_MAX_BODY][6];        // (nbody x 6) articulated bias wrench
  sd_real dof_U[SD_MAX_DOF][6];           // (ndof x 6) IA * S
  sd_real body_L[SD_MAX_BODY][9];         // (nbody x 9) Cholesky factor of D = S' IA S with
                                          //   reciprocal diagonal; 1/D itself for one dof
  sd_real dof_u[SD_MAX_DOF];              // (ndof) tau - S' pA
  sd_real body_a[SD_MAX_BODY][6];         // (nbody x 6) spatial acceleration

  // scratch of sd_step
  sd_real step_q[SD_MAX_Q];               // (nq) intermediate position
  sd_real step_qdot[SD_MAX_Q];            // (nq) position rate of the current stage
  sd_real step_kq[SD_MAX_Q];              // (nq) weighted sum of position rates
  sd_real step_qd[SD_MAX_DOF];            // (ndof) intermediate velocity
  sd_real step_kqd[SD_MAX_DOF];           // (ndof) weighted sum of velocity slopes
  sd_real step_qdd[SD_MAX_DOF];           // (ndof) acceleration of the current stage

  // set by the caller, applied by sd_rnea and sd_forward besides f_ext when body 0 floats free:
  // a force fixed in the base frame acting at a point fixed in body 0 (the supporting force of
  // the paper's pendulum experiment, whose direction in the body changes as the body turns)
  sd_real root_force[3];                  // (3) force in the base frame (N); zero for none
  sd_real root_point[3];                  // (3) its point of application in body 0's frame (m)

  int warning[SD_NWARNING];               // event counters, never reset by the core
} sd_data;

//---------------------------------- algorithms --------------------------------------------------

// Inverse dynamics by recursive Newton-Euler: the joint torques tau (ndof) that give the
// acceleration qdd (ndof) at (q (nq), qd (ndof)) under gravity and the external wrenches f_ext
// (nbody x 6, acting on each body, body frame, about its origin; NULL for none).
void sd_rnea(const sd_model* m, sd_data* d, const sd_real* q, const sd_real* qd,
             const sd_real* qdd, const sd_real* f_ext, sd_real* tau);

// Direct dynamics by the Armstrong-Green / articulated-body recursion: the acceleration qdd
// (ndof) under the joint torques tau, gravity and f_ext (as sd_rnea).
void sd_forward(const sd_model* m, sd_data* d, const sd_real* q, const sd_real* qd,
                const sd_real* tau, const sd_real* f_ext, sd_real* qdd);

// The inertial parameters of one body in the regressor, Pinocchio's order: mass, first moment
// h = m c, inertia about the body origin (xx, xy, yy, xz, yz, zz), in the core's body frame.
#define SD_NPARAM 10

// The joint-torque regressor: Y (ndof x SD_NPARAM*nbody, row-major) with sd_rnea's torque equal
// to Y pi plus the armature's part, pi = (mass, body_mcom, body_inertia0) of every body in order
// (parameters above). Gravity is in Y; external wrenches and the root force are not.
void sd_regressor(const sd_model* m, sd_data* d, const sd_real* q, const sd_real* qd,
                  const sd_real* qdd, sd_real* Y);

enum sd_integrator_ {
  SD_RK4 = 0,                // classical fourth-order Runge-Kutta, 4 sd_forward calls
  SD_EULER = 1,              // explicit Euler, 1 sd_forward call
};

// Advance (q, qd) in place by dt with tau and f_ext held constant over the step; a free root's
// quaternion is integrated with the rest and renormalized at the end of the step.
void sd_step(const sd_model* m, sd_data* d, sd_real* q, sd_real* qd, const sd_real* tau,
             const sd_real* f_ext, sd_real dt, int integrator);

// The position rate qdot (nq) at (q, qd): qd itself for hinges; for a free root the origin's
// velocity in the base frame and the quaternion rate q (x) (w, 0) / 2.
void sd_position_rate(const sd_model* m, const sd_real* q, const sd_real* qd, sd_real* qdot);

// Scale the quaternions in q (free root, ball joints) to unit length.
void sd_normalize_q(const sd_model* m, sd_real* q);

#ifdef __cplusplus
}
#endif

#include "sd_control.h"
#include "sd_observer.h"
#include "sd_trajectory.h"

#endif  // SERVODYN_H
