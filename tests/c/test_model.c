// test_model.c: model validation (sd_model_setup) and the inertia of solid primitives.
#include <math.h>
#include <string.h>

#include "fixtures.h"
#include "harness.h"

#define SDT_PI 3.14159265358979323846

static sd_model g_model;

// fill chain3 in, let the caller break one field, and expect setup to reject it
#define REJECT(mutation, code, body, reason)                                   \
  do {                                                                         \
    sdt_fill_chain3(&g_model);                                                 \
    mutation;                                                                  \
    int bad_ = -99;                                                            \
    int got_ = sd_model_setup(&g_model, &bad_);                                \
    sdt_context("%s", #mutation);                                              \
    EXPECT_INT(got_, code, reason);                                            \
    EXPECT_INT(bad_, body, "bad_body must name the offending body, -1 if none"); \
  } while (0)

static void accepts_valid_models(void) {
  int bad = -99;
  sdt_fill_chain3(&g_model);
  EXPECT_INT(sd_model_setup(&g_model, &bad), SD_OK, "chain3 is a valid model");
  EXPECT_INT(bad, -1, "no offending body in a valid model");
  EXPECT_INT(sdt_model_tree6(&g_model), SD_OK, "tree6 (two roots, a 0-dof joint) is valid");
}

static void rejects_bad_sizes(void) {
  REJECT(g_model.nbody = 0, SD_ERR_SIZE, -1, "a model needs at least one body");
  REJECT(g_model.nbody = -1, SD_ERR_SIZE, -1, "a negative body count is a size error");
  REJECT(g_model.nbody = SD_MAX_BODY + 1, SD_ERR_SIZE, -1, "nbody must fit SD_MAX_BODY");
  REJECT(g_model.ndof = SD_MAX_DOF + 1, SD_ERR_SIZE, -1, "ndof must fit SD_MAX_DOF");
  REJECT(g_model.ndof = -1, SD_ERR_SIZE, -1, "a negative dof count is a size error");
}

static void rejects_bad_parents(void) {
  REJECT(g_model.body_parent[1] = 1, SD_ERR_PARENT, 1, "a body cannot be its own parent");
  REJECT(g_model.body_parent[1] = 2, SD_ERR_PARENT, 1, "a parent must come before its child");
  REJECT(g_model.body_parent[0] = -2, SD_ERR_PARENT, 0, "-1 is the only parent below 0");
}

static void rejects_bad_dofs(void) {
  REJECT(g_model.body_dofnum[2] = 4, SD_ERR_DOFNUM, 2, "a joint has at most 3 dofs");
  REJECT(g_model.body_dofnum[2] = -1, SD_ERR_DOFNUM, 2, "a joint has at least 0 dofs");
  REJECT(g_model.body_dofadr[1] = 2, SD_ERR_DOFNUM, 1, "dof addresses must be consecutive");
}

static void rejects_nonfinite_numbers(void) {
  REJECT(g_model.body_pos[1][2] = (sd_real)NAN, SD_ERR_NONFINITE, 1, "NaN in a position");
  REJECT(g_model.body_com[2][0] = (sd_real)INFINITY, SD_ERR_NONFINITE, 2, "inf in a com");
  REJECT(g_model.gravity[1] = (sd_real)NAN, SD_ERR_NONFINITE, -1, "NaN in the gravity");
}

static void rejects_bad_mass(void) {
  REJECT(g_model.body_mass[2] = SD_R(-0.5), SD_ERR_MASS, 2, "a negative mass is unphysical");
  REJECT(g_model.body_mass[0] = SD_R(0.0), SD_ERR_MASS, 0, "a zero mass makes the dynamics singular");
}

static void set_inertia(int body, double xx, double yy, double zz, double xy, double xz,
                        double yz) {
  const double in[6] = {xx, yy, zz, xy, xz, yz};
  sdt_put(g_model.body_inertia[body], in, 6);
}

static void rejects_bad_inertia(void) {
  // eigenvalues 0.03, 0.01 and -0.01: the diagonal alone looks fine
  REJECT(set_inertia(1, 0.01, 0.01, 0.01, 0.02, 0, 0), SD_ERR_INERTIA, 1,
         "an inertia with a negative eigenvalue is not positive definite");
  REJECT(set_inertia(2, -0.001, 0.002, 0.002, 0, 0, 0), SD_ERR_INERTIA, 2,
         "a negative principal moment is not positive definite");
  REJECT(set_inertia(0, 0.05, 0.01, 0.01, 0, 0, 0), SD_ERR_INERTIA, 0,
         "Ixx > Iyy + Izz: no mass distribution has this inertia (triangle inequality)");
  REJECT(set_inertia(0, 0.01, 0.01, 0.03, 0, 0, 0), SD_ERR_INERTIA, 0,
         "Izz > Ixx + Iyy violates the triangle inequality");
}

static void accepts_thin_disk(void) {
  // a thin disk: Izz = Ixx + Iyy exactly, the limit of the triangle inequality
  int bad = -99;
  sdt_fill_chain3(&g_model);
  set_inertia(2, 0.001, 0.001, 0.002, 0, 0, 0);
  EXPECT_INT(sd_model_setup(&g_model, &bad), SD_OK, "a flat disk is a physical body");
}

static void rejects_bad_rotations(void) {
  REJECT(for (int k = 0; k < 9; k++) g_model.body_rot[1][k] *= SD_R(1.01), SD_ERR_ROTATION, 1,
         "a scaled matrix is not a rotation");
  REJECT(for (int k = 0; k < 3; k++) g_model.body_rot[2][k] = -g_model.body_rot[2][k],
         SD_ERR_ROTATION, 2, "a reflection (determinant -1) is not a rotation");
  REJECT(g_model.dof_rot[4][1] += SD_R(0.05), SD_ERR_ROTATION, 1,
         "the dof_rot of body 1's second dof is not orthonormal");
}

static void rejects_turned_first_dof(void) {
  double r[9];
  sdt_rotation(r, 1, 0, 0, 0.3);
  REJECT(sdt_put_rot(g_model.dof_rot[3], r), SD_ERR_FIRSTDOF, 1,
         "a joint's first dof frame is the joint frame (body_rot holds its placement)");
}

static void names_every_error(void) {
  const int codes[] = {SD_OK, SD_ERR_SIZE, SD_ERR_PARENT, SD_ERR_DOFNUM, SD_ERR_NONFINITE,
                       SD_ERR_ROTATION, SD_ERR_MASS, SD_ERR_INERTIA, SD_ERR_FIRSTDOF};
  for (size_t i = 0; i < sizeof codes / sizeof codes[0]; i++) {
    const char* text = sd_strerror(codes[i]);
    sdt_context("code %d", codes[i]);
    EXPECT_INT(text != NULL && text[0] != 0, 1, "every error code has a description");
    for (size_t j = 0; j < i && text; j++) {
      const char* other = sd_strerror(codes[j]);
      EXPECT_INT(other != NULL && strcmp(text, other) != 0, 1,
                 "two error codes must not share a description");
    }
  }
}

static void derives_origin_inertia(void) {
  // first moment h = m c; inertia about the origin by the parallel-axis theorem
  // I0 = Ic + m (|c|^2 1 - c c'), stored xx yy zz xy xz yz
  if (sdt_model_chain3(&g_model) != SD_OK) return;
  for (int i = 0; i < g_model.nbody; i++) {
    double m = (double)g_model.body_mass[i], c[3], Ic[6], I0[6];
    for (int j = 0; j < 3; j++) c[j] = (double)g_model.body_com[i][j];
    for (int j = 0; j < 6; j++) Ic[j] = (double)g_model.body_inertia[i][j];
    double cc = c[0]*c[0] + c[1]*c[1] + c[2]*c[2];
    I0[0] = Ic[0] + m * (cc - c[0]*c[0]);
    I0[1] = Ic[1] + m * (cc - c[1]*c[1]);
    I0[2] = Ic[2] + m * (cc - c[2]*c[2]);
    I0[3] = Ic[3] - m * c[0]*c[1];
    I0[4] = Ic[4] - m * c[0]*c[2];
    I0[5] = Ic[5] - m * c[1]*c[2];
    sdt_context("body %d", i);
    for (int j = 0; j < 3; j++) {
      EXPECT_NEAR(g_model.body_mcom[i][j], m * c[j], SDT_REL * m * 0.2, "body_mcom = mass * com");
    }
    for (int j = 0; j < 6; j++) {
      EXPECT_NEAR(g_model.body_inertia0[i][j], I0[j], SDT_REL * 0.1,
                  "body_inertia0 = inertia about the origin (parallel-axis theorem)");
    }
    for (int r = 0; r < 3; r++) {
      for (int k = 0; k < 3; k++) {
        EXPECT_NEAR(g_model.body_rotT[i][3*r+k], g_model.body_rot[i][3*k+r], 0,
                    "body_rotT is the transpose of body_rot");
      }
    }
  }
}

//---------------------------------- inertia primitives ------------------------------------------

// check a computed inertia against xx yy zz xy xz yz, relative to the largest moment
static void expect_inertia(const sd_real got[6], const double want[6], const char* reason) {
  double scale = fmax(want[0], fmax(want[1], want[2]));
  for (int j = 0; j < 6; j++) {
    sdt_context("component %d of xx yy zz xy xz yz", j);
    EXPECT_NEAR(got[j], want[j], SDT_REL * scale, reason);
  }
}

static void cylinder_inertia(void) {
  sd_real in[6];
  const double m = 2.0, r = 0.05, L = 0.3;
  EXPECT_INT(sd_inertia_cylinder(SD_R(2.0), SD_R(0.05), SD_R(0.3), in), 0, "valid cylinder");
  const double want[6] = {m * (3*r*r + L*L) / 12, m * (3*r*r + L*L) / 12, m * r*r / 2, 0, 0, 0};
  expect_inertia(in, want, "solid cylinder about its centroid: Izz = m r^2/2, Ixx = m(3r^2+L^2)/12");
  EXPECT_INT(sd_inertia_cylinder(SD_R(2.0), SD_R(0.0), SD_R(0.3), in), -1, "zero radius");
  EXPECT_INT(sd_inertia_cylinder(SD_R(2.0), SD_R(0.05), SD_R(-0.3), in), -1, "negative length");
}

static void sphere_inertia(void) {
  sd_real in[6];
  const double m = 3.0, r = 0.1;
  EXPECT_INT(sd_inertia_sphere(SD_R(3.0), SD_R(0.1), in), 0, "valid sphere");
  const double want[6] = {0.4 * m*r*r, 0.4 * m*r*r, 0.4 * m*r*r, 0, 0, 0};
  expect_inertia(in, want, "solid sphere: I = 2/5 m r^2");
  EXPECT_INT(sd_inertia_sphere(SD_R(3.0), SD_R(0.0), in), -1, "zero radius");
}

static void ellipsoid_inertia(void) {
  sd_real in[6];
  const double m = 1.5, a = 0.1, b = 0.2, c = 0.3;
  EXPECT_INT(sd_inertia_ellipsoid(SD_R(1.5), SD_R(0.1), SD_R(0.2), SD_R(0.3), in), 0,
             "valid ellipsoid");
  const double want[6] = {m * (b*b + c*c) / 5, m * (a*a + c*c) / 5, m * (a*a + b*b) / 5, 0, 0, 0};
  expect_inertia(in, want, "solid ellipsoid with semi-axes a, b, c: Ixx = m(b^2+c^2)/5 ...");
  sd_real sphere[6];
  sd_inertia_sphere(SD_R(1.5), SD_R(0.2), sphere);
  sd_inertia_ellipsoid(SD_R(1.5), SD_R(0.2), SD_R(0.2), SD_R(0.2), in);
  const double want_sphere[6] = {(double)sphere[0], (double)sphere[1], (double)sphere[2], 0, 0, 0};
  expect_inertia(in, want_sphere, "an ellipsoid with equal semi-axes is a sphere");
  EXPECT_INT(sd_inertia_ellipsoid(SD_R(1.5), SD_R(0.1), SD_R(0.2), SD_R(0.0), in), -1,
             "zero semi-axis");
}

// frustum by 3-point Gauss-Legendre quadrature over z, exact for the degree-4 integrands
static void frustum_reference(double m, double r0, double r1, double L, double* com_z,
                              double want[6]) {
  const double node[3] = {-sqrt(0.6), 0, sqrt(0.6)}, weight[3] = {5.0/9, 8.0/9, 5.0/9};
  double volume = 0, first = 0;
  for (int k = 0; k < 3; k++) {
    double z = 0.5 * L * (1 + node[k]), r = r0 + (r1 - r0) * z / L, w = 0.5 * L * weight[k];
    volume += w * SDT_PI * r*r;
    first += w * SDT_PI * r*r * z;
  }
  double rho = m / volume, zc = first / volume, ixx = 0, izz = 0;
  for (int k = 0; k < 3; k++) {
    double z = 0.5 * L * (1 + node[k]), r = r0 + (r1 - r0) * z / L, w = 0.5 * L * weight[k];
    // a disk of radius r at height z: Izz = r^2/2, Ixx = r^2/4 + (z - zc)^2 per unit mass
    izz += w * rho * SDT_PI * r*r * r*r / 2;
    ixx += w * rho * SDT_PI * r*r * (r*r / 4 + (z - zc) * (z - zc));
  }
  *com_z = zc;
  want[0] = want[1] = ixx;
  want[2] = izz;
  want[3] = want[4] = want[5] = 0;
}

static void frustum_inertia(void) {
  const double cases[2][4] = {{1.2, 0.06, 0.03, 0.25}, {0.7, 0.02, 0.05, 0.4}};
  for (int c = 0; c < 2; c++) {
    double m = cases[c][0], r0 = cases[c][1], r1 = cases[c][2], L = cases[c][3];
    sd_real in[6], com_z = SD_R(-1.0);
    double want[6], want_z;
    frustum_reference(m, r0, r1, L, &want_z, want);
    EXPECT_INT(sd_inertia_frustum((sd_real)m, (sd_real)r0, (sd_real)r1, (sd_real)L, &com_z, in),
               0, "valid frustum");
    double closed_z = L * (r0*r0 + 2*r0*r1 + 3*r1*r1) / (4 * (r0*r0 + r0*r1 + r1*r1));
    sdt_context("frustum m %g r0 %g r1 %g L %g", m, r0, r1, L);
    EXPECT_NEAR(want_z, closed_z, 1e-14, "the quadrature reference itself is exact (sanity)");
    EXPECT_NEAR(com_z, closed_z, SDT_REL * L,
                "centroid z = L(r0^2 + 2 r0 r1 + 3 r1^2) / (4(r0^2 + r0 r1 + r1^2))");
    expect_inertia(in, want, "frustum inertia about its centroid equals the integral over disks");
  }
  // a frustum with equal radii is a cylinder with its base at z = 0
  sd_real in[6], cyl[6], com_z;
  sd_inertia_frustum(SD_R(2.0), SD_R(0.05), SD_R(0.05), SD_R(0.3), &com_z, in);
  sd_inertia_cylinder(SD_R(2.0), SD_R(0.05), SD_R(0.3), cyl);
  EXPECT_NEAR(com_z, 0.15, SDT_REL, "a cylinder's centroid is at half its length");
  const double want[6] = {(double)cyl[0], (double)cyl[1], (double)cyl[2], 0, 0, 0};
  expect_inertia(in, want, "frustum with r0 == r1 equals the cylinder");
  EXPECT_INT(sd_inertia_frustum(SD_R(1.0), SD_R(-0.1), SD_R(0.1), SD_R(0.3), &com_z, in), -1,
             "negative radius");
  EXPECT_INT(sd_inertia_frustum(SD_R(1.0), SD_R(0.1), SD_R(0.1), SD_R(0.0), &com_z, in), -1,
             "zero length");
}

const sdt_test sdt_model_tests[] = {
  {"accepts_valid_models", accepts_valid_models},
  {"rejects_bad_sizes", rejects_bad_sizes},
  {"rejects_bad_parents", rejects_bad_parents},
  {"rejects_bad_dofs", rejects_bad_dofs},
  {"rejects_nonfinite_numbers", rejects_nonfinite_numbers},
  {"rejects_bad_mass", rejects_bad_mass},
  {"rejects_bad_inertia", rejects_bad_inertia},
  {"accepts_thin_disk", accepts_thin_disk},
  {"rejects_bad_rotations", rejects_bad_rotations},
  {"rejects_turned_first_dof", rejects_turned_first_dof},
  {"names_every_error", names_every_error},
  {"derives_origin_inertia", derives_origin_inertia},
  {"cylinder_inertia", cylinder_inertia},
  {"sphere_inertia", sphere_inertia},
  {"ellipsoid_inertia", ellipsoid_inertia},
  {"frustum_inertia", frustum_inertia},
  {0, 0},
};
