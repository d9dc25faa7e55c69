// test_rnea.c: inverse dynamics (sd_rnea) against closed forms and against the Lagrange
// equations of the reference energies (fixtures.c), by finite differences.
#include <math.h>
#include <string.h>

#include "fixtures.h"
#include "harness.h"

static sd_model g_model;
static sd_data g_data;

// a pendulum: one hinge about the base z axis, gravity along -y, com at distance l along -y
static const double kMass = 1.3, kLength = 0.35, kG = 9.81, kIzz = 0.0035;

static int pendulum(sd_model* m) {
  memset(m, 0, sizeof *m);
  const double g[3] = {0, -kG, 0}, pos[3] = {0.1, 0.2, 0.3}, com[3] = {0, -kLength, 0};
  // products xz and yz only load the bearings; they must not reach the hinge torque
  const double inertia[6] = {0.004, 0.003, kIzz, 0, 0.0003, 0.0002};
  const double eye[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  m->nbody = 1;
  m->ndof = 1;
  m->body_parent[0] = -1;
  m->body_dofnum[0] = 1;
  m->body_dofadr[0] = 0;
  sdt_put(m->gravity, g, 3);
  sdt_put(m->body_pos[0], pos, 3);
  sdt_put_rot(m->body_rot[0], eye);
  sdt_put_rot(m->dof_rot[0], eye);
  m->body_mass[0] = (sd_real)kMass;
  sdt_put(m->body_com[0], com, 3);
  sdt_put(m->body_inertia[0], inertia, 6);
  int bad;
  int code = sd_model_setup(m, &bad);
  EXPECT_INT(code, SD_OK, "the pendulum is a valid model");
  return code;
}

static void pendulum_torque(void) {
  if (pendulum(&g_model) != SD_OK) return;
  const double cases[][3] = {{0, 0, 0},    {0.3, 0, 2.0},  {-1.2, 1.7, -5.0},
                             {2.5, -3.0, 0.5}, {3.1, 4.0, 0}, {-2.0, 0, 10.0}};
  for (size_t c = 0; c < sizeof cases / sizeof cases[0]; c++) {
    sd_real q = (sd_real)cases[c][0], qd = (sd_real)cases[c][1], qdd = (sd_real)cases[c][2];
    sd_real tau = SD_R(-99.0);
    memset(&g_data, 0, sizeof g_data);
    sd_rnea(&g_model, &g_data, &q, &qd, &qdd, NULL, &tau);
    double gravity = kMass * kG * kLength * sin((double)q);
    double inertial = (kIzz + kMass * kLength * kLength) * (double)qdd;
    sdt_context("q %g qd %g qdd %g", (double)q, (double)qd, (double)qdd);
    EXPECT_NEAR(tau, gravity + inertial, SDT_REL * (fabs(gravity) + fabs(inertial) + 1),
                "hinge torque = m g l sin(q) + (Izz + m l^2) qdd, with no velocity term");
  }
}

// the joint torques that hold the model still: G(q) = rnea(q, 0, 0)
static void gravity_torque(const sd_model* m, const sd_real* q, sd_real* g) {
  static sd_real zero[SDT_MAXN];
  memset(zero, 0, sizeof zero);
  sd_rnea(m, &g_data, q, zero, zero, NULL, g);
}

static double potential(const sd_model* m, const double* q) {
  static sdt_kin kin;
  static double zero[SDT_MAXN];
  sdt_kinematics(m, q, zero, &kin);
  return sdt_potential_energy(m, &kin);
}

static double kinetic(const sd_model* m, const double* q, const double* qd) {
  static sdt_kin kin;
  sdt_kinematics(m, q, qd, &kin);
  return sdt_kinetic_energy(m, &kin);
}

static void gravity_is_potential_gradient(void) {
  const double h = 1e-5;
  unsigned seed = 11;
  for (int model = 0; model < SDT_NMODEL; model++) {
    const char* name;
    if (sdt_model_by_index(&g_model, model, &name) != SD_OK) continue;
    int n = g_model.ndof;
    for (int trial = 0; trial < 3; trial++) {
      sd_real q[SDT_MAXN], g[SDT_MAXN], ref[SDT_MAXN];
      double qx[SDT_MAXN];
      sdt_random_vector(&seed, -2, 2, n, q, qx);
      memset(&g_data, 0, sizeof g_data);
      gravity_torque(&g_model, q, g);
      for (int k = 0; k < n; k++) {
        double save = qx[k];
        qx[k] = save + h;
        double up = potential(&g_model, qx);
        qx[k] = save - h;
        double down = potential(&g_model, qx);
        qx[k] = save;
        ref[k] = (sd_real)((up - down) / (2 * h));
      }
      sdt_context("model %s, trial %d", name, trial);
      EXPECT_LE(sdt_maxdiff(g, ref, n), SDT_TOL_FD * (1 + sdt_maxabs(ref, n)),
                "the torque that holds the model still is the gradient of its potential energy");
    }
  }
}

static void mass_matrix_is_kinetic_energy(void) {
  unsigned seed = 12;
  for (int model = 0; model < SDT_NMODEL; model++) {
    const char* name;
    if (sdt_model_by_index(&g_model, model, &name) != SD_OK) continue;
    int n = g_model.ndof;
    for (int trial = 0; trial < 3; trial++) {
      sd_real q[SDT_MAXN], qd[SDT_MAXN], zero[SDT_MAXN], g[SDT_MAXN], tau[SDT_MAXN];
      sd_real M[SDT_MAXN][SDT_MAXN];
      double qx[SDT_MAXN], qdx[SDT_MAXN];
      sdt_random_vector(&seed, -2, 2, n, q, qx);
      sdt_random_vector(&seed, -3, 3, n, qd, qdx);
      memset(zero, 0, sizeof zero);
      memset(&g_data, 0, sizeof g_data);
      gravity_torque(&g_model, q, g);
      // M qd = rnea(q, 0, qd) - G(q): kinetic energy = qd' M qd / 2
      sd_rnea(&g_model, &g_data, q, zero, qd, NULL, tau);
      for (int k = 0; k < n; k++) tau[k] -= g[k];
      double ke = kinetic(&g_model, qx, qdx);
      sdt_context("model %s, trial %d", name, trial);
      EXPECT_NEAR(0.5 * sdt_dot(qd, tau, n), ke, 10 * SDT_REL * (ke + 1),
                  "qd' M qd / 2 from rnea equals the kinetic energy of the bodies");
      // columns of M, one unit acceleration at a time: M must be symmetric positive
      for (int j = 0; j < n; j++) {
        sd_real e[SDT_MAXN];
        memset(e, 0, sizeof e);
        e[j] = SD_R(1.0);
        sd_rnea(&g_model, &g_data, q, zero, e, NULL, tau);
        for (int k = 0; k < n; k++) M[k][j] = tau[k] - g[k];
      }
      double asym = 0, mindiag = 1e300;
      for (int j = 0; j < n; j++) {
        mindiag = fmin(mindiag, (double)M[j][j]);
        for (int k = 0; k < j; k++) asym = fmax(asym, fabs((double)M[j][k] - (double)M[k][j]));
      }
      EXPECT_LE(asym, 10 * SDT_REL, "the joint-space inertia matrix is symmetric");
      EXPECT_GE(mindiag, 1e-6, "every dof has a positive inertia");
    }
  }
}

// the Lagrange equations of L = T - V along the path q(t) = q + t qd + t^2/2 qdd:
// tau = d/dt dT/dqd - dT/dq + dV/dq, each derivative a central difference
static void lagrange_torque(const sd_model* m, const double* q, const double* qd,
                            const double* qdd, double* tau) {
  const double h = 1e-4, dv = 1e-3;   // dT/dqd is linear in qd: its difference has no truncation
  int n = m->ndof;
  for (int k = 0; k < n; k++) {
    double momentum[2];
    for (int side = 0; side < 2; side++) {
      double t = side ? h : -h, qt[SDT_MAXN], qdt[SDT_MAXN];
      for (int j = 0; j < n; j++) {
        qt[j] = q[j] + t * qd[j] + 0.5 * t * t * qdd[j];
        qdt[j] = qd[j] + t * qdd[j];
      }
      qdt[k] += dv;
      double up = kinetic(m, qt, qdt);
      qdt[k] -= 2 * dv;
      double down = kinetic(m, qt, qdt);
      momentum[side] = (up - down) / (2 * dv);
    }
    double qk[SDT_MAXN];
    memcpy(qk, q, (size_t)n * sizeof(double));
    qk[k] = q[k] + h;
    double t_up = kinetic(m, qk, qd), v_up = potential(m, qk);
    qk[k] = q[k] - h;
    double t_down = kinetic(m, qk, qd), v_down = potential(m, qk);
    tau[k] = (momentum[1] - momentum[0]) / (2 * h) - (t_up - t_down) / (2 * h) +
             (v_up - v_down) / (2 * h);
  }
}

static void rnea_matches_lagrange(void) {
  unsigned seed = 13;
  for (int model = 0; model < SDT_NMODEL; model++) {
    const char* name;
    if (sdt_model_by_index(&g_model, model, &name) != SD_OK) continue;
    int n = g_model.ndof;
    for (int trial = 0; trial < 4; trial++) {
      sd_real q[SDT_MAXN], qd[SDT_MAXN], qdd[SDT_MAXN], tau[SDT_MAXN], ref[SDT_MAXN];
      double qx[SDT_MAXN], qdx[SDT_MAXN], qddx[SDT_MAXN], refx[SDT_MAXN];
      sdt_random_vector(&seed, -2, 2, n, q, qx);
      sdt_random_vector(&seed, -3, 3, n, qd, qdx);
      sdt_random_vector(&seed, -5, 5, n, qdd, qddx);
      memset(&g_data, 0, sizeof g_data);
      sd_rnea(&g_model, &g_data, q, qd, qdd, NULL, tau);
      lagrange_torque(&g_model, qx, qdx, qddx, refx);
      sdt_put(ref, refx, n);
      sdt_context("model %s, trial %d", name, trial);
      EXPECT_LE(sdt_maxdiff(tau, ref, n), SDT_TOL_FD * 10 * (1 + sdt_maxabs(ref, n)),
                "rnea torques satisfy the Lagrange equations of the bodies' energies");
    }
  }
}

static void external_wrench_power(void) {
  // rnea(f_ext) - rnea(0) = -J' f_ext, so qd . (difference) = -(power of f_ext at velocity qd)
  unsigned seed = 14;
  for (int model = 0; model < SDT_NMODEL; model++) {
    const char* name;
    if (sdt_model_by_index(&g_model, model, &name) != SD_OK) continue;
    int n = g_model.ndof, nb = g_model.nbody;
    for (int trial = 0; trial < 3; trial++) {
      sd_real q[SDT_MAXN], qd[SDT_MAXN], zero[SDT_MAXN], with[SDT_MAXN], without[SDT_MAXN];
      sd_real f_ext[6 * SDT_MAXN];
      double qx[SDT_MAXN], qdx[SDT_MAXN];
      sdt_random_vector(&seed, -2, 2, n, q, qx);
      sdt_random_vector(&seed, -3, 3, n, qd, qdx);
      sdt_random_vector(&seed, -4, 4, 6 * nb, f_ext, NULL);
      memset(zero, 0, sizeof zero);
      memset(&g_data, 0, sizeof g_data);
      sd_rnea(&g_model, &g_data, q, zero, zero, f_ext, with);
      sd_rnea(&g_model, &g_data, q, zero, zero, NULL, without);
      for (int k = 0; k < n; k++) with[k] -= without[k];
      static sdt_kin kin;
      sdt_kinematics(&g_model, qx, qdx, &kin);
      double power = sdt_wrench_power(&g_model, &kin, f_ext);
      sdt_context("model %s, trial %d", name, trial);
      EXPECT_NEAR(sdt_dot(qd, with, n), -power, 10 * SDT_REL * (fabs(power) + 10),
                  "f_ext = (torque about the body origin; force) in the body frame: "
                  "its joint torques do the same work as the wrench");
    }
  }
}

static void nonfinite_input_zeroes_output(void) {
  if (sdt_model_chain3(&g_model) != SD_OK) return;
  int n = g_model.ndof;
  sd_real q[SDT_MAXN], qd[SDT_MAXN], qdd[SDT_MAXN], tau[SDT_MAXN], f_ext[6 * SDT_MAXN];
  unsigned seed = 15;
  sdt_random_vector(&seed, -1, 1, n, q, NULL);
  sdt_random_vector(&seed, -1, 1, n, qd, NULL);
  sdt_random_vector(&seed, -1, 1, n, qdd, NULL);
  memset(f_ext, 0, sizeof f_ext);
  memset(&g_data, 0, sizeof g_data);
  q[1] = (sd_real)NAN;
  sd_rnea(&g_model, &g_data, q, qd, qdd, NULL, tau);
  sdt_context("q[1] = NaN");
  EXPECT_LE(sdt_maxabs(tau, n), 0, "a non-finite input gives zero torques, never NaN");
  EXPECT_INT(g_data.warning[SD_WARN_NONFINITE] >= 1, 1, "the event is counted in warning[]");
  q[1] = SD_R(0.5);
  f_ext[6 * (g_model.nbody - 1)] = (sd_real)INFINITY;   // a torque on the last body
  int before = g_data.warning[SD_WARN_NONFINITE];
  sd_rnea(&g_model, &g_data, q, qd, qdd, f_ext, tau);
  sdt_context("f_ext = inf");
  EXPECT_LE(sdt_maxabs(tau, n), 0, "a non-finite wrench gives zero torques");
  EXPECT_INT(g_data.warning[SD_WARN_NONFINITE] > before, 1, "the event is counted again");
}

const sdt_test sdt_rnea_tests[] = {
  {"pendulum_torque", pendulum_torque},
  {"gravity_is_potential_gradient", gravity_is_potential_gradient},
  {"mass_matrix_is_kinetic_energy", mass_matrix_is_kinetic_energy},
  {"rnea_matches_lagrange", rnea_matches_lagrange},
  {"external_wrench_power", external_wrench_power},
  {"nonfinite_input_zeroes_output", nonfinite_input_zeroes_output},
  {0, 0},
};
