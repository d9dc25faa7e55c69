// fixtures.h: test models, states and reference mechanics for the C core tests.
//
// The reference mechanics (kinematics, kinetic and potential energy, power of external
// wrenches) are computed here in double, straight from the model fields and the conventions
// of servodyn.h, sharing no code with the core: a test compares two independent routes to the
// same physical number.
#ifndef SDT_FIXTURES_H
#define SDT_FIXTURES_H

#include "servodyn.h"

// tolerances of the two builds; float ones are loose because sd_real has 24 bits
#ifdef SD_SINGLE
#define SDT_TOL_INVERSE 1e-4      // |forward(rnea(qdd)) - qdd| / (1 + |qdd|)
#define SDT_REL 1e-5              // relative error of one well-conditioned evaluation
#define SDT_TOL_FD 1e-4           // relative error of a finite-difference comparison
#else
#define SDT_TOL_INVERSE 1e-10
#define SDT_REL 1e-12
#define SDT_TOL_FD 1e-7           // central differences: h^2 truncation plus eps/h rounding
#endif

#define SDT_MAXN 16               // largest test model: bodies and dofs

// deterministic pseudo-random numbers in [lo, hi)
double sdt_uniform(unsigned* state, double lo, double hi);

// rotation matrix (row-major) about the axis (x, y, z), normalised here, by angle
void sdt_rotation(double R[9], double x, double y, double z, double angle);
// store a double 3x3 into a model field
void sdt_put_rot(sd_real dst[9], const double R[9]);
// set dst[0..n) from doubles
void sdt_put(sd_real* dst, const double* src, int n);

// A valid inertia about the com: principal moments (a, b, c), which must satisfy the triangle
// inequality, turned by the rotation R. Stored as xx yy zz xy xz yz.
void sdt_inertia(sd_real dst[6], double a, double b, double c, const double R[9]);

// Test models. Each is filled in, passed through sd_model_setup (a check: it must be
// accepted) and returns the setup code, SD_OK when the model is usable.
// chain3: 3-dof, 2-dof and 1-dof joints in a chain, generic fixed rotations, 6 dofs
int sdt_model_chain3(sd_model* m);
// tree6: two roots, a branch, a 0-dof joint; joints of 3, 2, 1, 0, 1, 1 dofs, 8 dofs
int sdt_model_tree6(sd_model* m);
// the models the dynamics tests loop over
#define SDT_NMODEL 2
int sdt_model_by_index(sd_model* m, int index, const char** name);
// fill chain3 in without calling sd_model_setup (for the validation tests)
void sdt_fill_chain3(sd_model* m);

// The ball joints of both models lock (their three axes become coplanar) at a middle angle
// q1 = +-pi/2, where the joint-space inertia is singular: states for the direct dynamics keep
// |q| <= SDT_QMAX so the tests measure the algorithms, not the conditioning.
#define SDT_QMAX 1.2

// A random state, rounded to sd_real; the double copies hold the same (rounded) values.
void sdt_random_vector(unsigned* seed, double lo, double hi, int n, sd_real* r, double* d);

// Reference kinematics in the base frame.
typedef struct sdt_kin_ {
  double R[SDT_MAXN][9];      // base_R_body
  double p[SDT_MAXN][3];      // body origin
  double w[SDT_MAXN][3];      // angular velocity
  double v[SDT_MAXN][3];      // velocity of the body origin
} sdt_kin;

void sdt_kinematics(const sd_model* m, const double* q, const double* qd, sdt_kin* k);
double sdt_kinetic_energy(const sd_model* m, const sdt_kin* k);
double sdt_potential_energy(const sd_model* m, const sdt_kin* k);
// power of the external wrenches f_ext (nbody x 6: torque about the origin; force, body frame)
double sdt_wrench_power(const sd_model* m, const sdt_kin* k, const sd_real* f_ext);

// largest |a[i] - b[i]|
double sdt_maxdiff(const sd_real* a, const sd_real* b, int n);
// largest |a[i]|
double sdt_maxabs(const sd_real* a, int n);
// sum of a[i] * b[i] in double
double sdt_dot(const sd_real* a, const sd_real* b, int n);

#endif  // SDT_FIXTURES_H
