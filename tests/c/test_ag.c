// test_ag.c: direct dynamics (sd_forward, Armstrong-Green / articulated body) against inverse
// dynamics and against the energy balance of the reference mechanics.
#include <math.h>
#include <string.h>

#include "fixtures.h"
#include "harness.h"

static sd_model g_model;
static sd_data g_data;

static void forward_inverts_rnea(void) {
  unsigned seed = 21;
  for (int model = 0; model < SDT_NMODEL; model++) {
    const char* name;
    if (sdt_model_by_index(&g_model, model, &name) != SD_OK) continue;
    int n = g_model.ndof, nb = g_model.nbody;
    for (int trial = 0; trial < 8; trial++) {
      int with_wrench = trial % 2;
      sd_real q[SDT_MAXN], qd[SDT_MAXN], qdd[SDT_MAXN], tau[SDT_MAXN], back[SDT_MAXN];
      sd_real f_ext[6 * SDT_MAXN];
      sdt_random_vector(&seed, -SDT_QMAX, SDT_QMAX, n, q, NULL);
      sdt_random_vector(&seed, -3, 3, n, qd, NULL);
      sdt_random_vector(&seed, -3, 3, n, qdd, NULL);
      sdt_random_vector(&seed, -4, 4, 6 * nb, f_ext, NULL);
      const sd_real* f = with_wrench ? f_ext : NULL;
      memset(&g_data, 0, sizeof g_data);
      sdt_context("model %s, trial %d, %s", name, trial, with_wrench ? "f_ext" : "no f_ext");
      // qdd -> tau -> qdd
      sd_rnea(&g_model, &g_data, q, qd, qdd, f, tau);
      sd_forward(&g_model, &g_data, q, qd, tau, f, back);
      // relative to the accelerations: float keeps 7 digits and the joint-space inertia of
      // these models has a condition number near 1e3 (a float dense solve does no better)
      EXPECT_LE(sdt_maxdiff(back, qdd, n), SDT_TOL_INVERSE * (1 + sdt_maxabs(qdd, n)),
                "forward(rnea(qdd)) == qdd: the two algorithms solve the same equations");
      // tau -> qdd -> tau
      sdt_random_vector(&seed, -5, 5, n, tau, NULL);
      sd_forward(&g_model, &g_data, q, qd, tau, f, qdd);
      sd_rnea(&g_model, &g_data, q, qd, qdd, f, back);
      EXPECT_LE(sdt_maxdiff(back, tau, n), SDT_TOL_INVERSE * (1 + sdt_maxabs(tau, n)),
                "rnea(forward(tau)) == tau");
      EXPECT_INT(g_data.warning[SD_WARN_NONFINITE] + g_data.warning[SD_WARN_SINGULAR], 0,
                 "a valid model in a finite state raises no warning");
    }
  }
}

static double kinetic(const sd_model* m, const double* q, const double* qd) {
  static sdt_kin kin;
  sdt_kinematics(m, q, qd, &kin);
  return sdt_kinetic_energy(m, &kin);
}

static void power_balance(void) {
  // along the motion qdd = forward(q, qd, tau): dT/dt = qd . (tau - G(q)) + power of f_ext,
  // the velocity-product terms doing no work; dT/dt by a five-point difference on the path
  const double h = 1e-5;
  unsigned seed = 22;
  for (int model = 0; model < SDT_NMODEL; model++) {
    const char* name;
    if (sdt_model_by_index(&g_model, model, &name) != SD_OK) continue;
    int n = g_model.ndof, nb = g_model.nbody;
    for (int trial = 0; trial < 6; trial++) {
      int with_wrench = trial % 2;
      sd_real q[SDT_MAXN], qd[SDT_MAXN], qdd[SDT_MAXN], tau[SDT_MAXN], g[SDT_MAXN];
      sd_real zero[SDT_MAXN], f_ext[6 * SDT_MAXN];
      double qx[SDT_MAXN], qdx[SDT_MAXN];
      sdt_random_vector(&seed, -SDT_QMAX, SDT_QMAX, n, q, qx);
      sdt_random_vector(&seed, -3, 3, n, qd, qdx);
      sdt_random_vector(&seed, -5, 5, n, tau, NULL);
      sdt_random_vector(&seed, -4, 4, 6 * nb, f_ext, NULL);
      const sd_real* f = with_wrench ? f_ext : NULL;
      memset(zero, 0, sizeof zero);
      memset(&g_data, 0, sizeof g_data);
      sd_forward(&g_model, &g_data, q, qd, tau, f, qdd);
      sd_rnea(&g_model, &g_data, q, zero, zero, NULL, g);
      double ke[4];
      const double at[4] = {-2 * h, -h, h, 2 * h};
      for (int side = 0; side < 4; side++) {
        double t = at[side], qt[SDT_MAXN], qdt[SDT_MAXN];
        for (int j = 0; j < n; j++) {
          qt[j] = qx[j] + t * qdx[j] + 0.5 * t * t * (double)qdd[j];
          qdt[j] = qdx[j] + t * (double)qdd[j];
        }
        ke[side] = kinetic(&g_model, qt, qdt);
      }
      double rate = (ke[0] - 8 * ke[1] + 8 * ke[2] - ke[3]) / (12 * h), power = 0;
      for (int j = 0; j < n; j++) power += qdx[j] * ((double)tau[j] - (double)g[j]);
      if (f) {
        static sdt_kin kin;
        sdt_kinematics(&g_model, qx, qdx, &kin);
        power += sdt_wrench_power(&g_model, &kin, f);
      }
      sdt_context("model %s, trial %d, %s", name, trial, with_wrench ? "f_ext" : "no f_ext");
      EXPECT_NEAR(rate, power, SDT_TOL_FD * 10 * (fabs(power) + 1),
                  "d/dt kinetic energy = qd . (tau - gravity torque) + power of f_ext");
    }
  }
}

static void nonfinite_input_zeroes_output(void) {
  if (sdt_model_tree6(&g_model) != SD_OK) return;
  int n = g_model.ndof;
  sd_real q[SDT_MAXN], qd[SDT_MAXN], tau[SDT_MAXN], qdd[SDT_MAXN];
  unsigned seed = 23;
  sdt_random_vector(&seed, -1, 1, n, q, NULL);
  sdt_random_vector(&seed, -1, 1, n, qd, NULL);
  sdt_random_vector(&seed, -1, 1, n, tau, NULL);
  memset(&g_data, 0, sizeof g_data);
  tau[n - 1] = (sd_real)NAN;
  sd_forward(&g_model, &g_data, q, qd, tau, NULL, qdd);
  sdt_context("tau[last] = NaN");
  EXPECT_LE(sdt_maxabs(qdd, n), 0, "a non-finite input gives zero accelerations, never NaN");
  EXPECT_INT(g_data.warning[SD_WARN_NONFINITE] >= 1, 1, "the event is counted in warning[]");
  tau[n - 1] = SD_R(0.0);
  qd[0] = (sd_real)INFINITY;
  int before = g_data.warning[SD_WARN_NONFINITE];
  sd_forward(&g_model, &g_data, q, qd, tau, NULL, qdd);
  sdt_context("qd[0] = inf");
  EXPECT_LE(sdt_maxabs(qdd, n), 0, "an infinite velocity gives zero accelerations");
  EXPECT_INT(g_data.warning[SD_WARN_NONFINITE] > before, 1, "the event is counted again");
}

const sdt_test sdt_ag_tests[] = {
  {"forward_inverts_rnea", forward_inverts_rnea},
  {"power_balance", power_balance},
  {"nonfinite_input_zeroes_output", nonfinite_input_zeroes_output},
  {0, 0},
};
