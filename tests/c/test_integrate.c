// test_integrate.c: the integrators of sd_step against their definitions, their order of
// convergence and the energy conservation of a passive model.
#include <math.h>
#include <string.h>

#include "fixtures.h"
#include "harness.h"

static sd_model g_model;
static sd_data g_data;

// a gentle start for long runs: the motion stays clear of the ball joints' gimbal lock
static void gentle_state(unsigned* seed, int n, sd_real* q, sd_real* qd) {
  sdt_random_vector(seed, -0.4, 0.4, n, q, NULL);
  sdt_random_vector(seed, -0.5, 0.5, n, qd, NULL);
}

static void random_state(unsigned* seed, int n, sd_real* q, sd_real* qd, sd_real* tau) {
  sdt_random_vector(seed, -SDT_QMAX, SDT_QMAX, n, q, NULL);
  sdt_random_vector(seed, -2, 2, n, qd, NULL);
  if (tau) sdt_random_vector(seed, -3, 3, n, tau, NULL);
}

static void euler_step_definition(void) {
  if (sdt_model_chain3(&g_model) != SD_OK) return;
  int n = g_model.ndof;
  sd_real q[SDT_MAXN], qd[SDT_MAXN], tau[SDT_MAXN], qdd[SDT_MAXN], q1[SDT_MAXN], qd1[SDT_MAXN];
  const sd_real dt = SD_R(0.01);
  unsigned seed = 31;
  random_state(&seed, n, q, qd, tau);
  memset(&g_data, 0, sizeof g_data);
  sd_forward(&g_model, &g_data, q, qd, tau, NULL, qdd);
  for (int k = 0; k < n; k++) {
    q1[k] = q[k] + dt * qd[k];
    qd1[k] = qd[k] + dt * qdd[k];
  }
  sd_step(&g_model, &g_data, q, qd, tau, NULL, dt, SD_EULER);
  EXPECT_LE(sdt_maxdiff(q, q1, n), SDT_REL * 10, "explicit Euler: q += dt qd (the old qd)");
  EXPECT_LE(sdt_maxdiff(qd, qd1, n), SDT_REL * 10 * (1 + sdt_maxabs(qdd, n)),
            "explicit Euler: qd += dt forward(q, qd, tau)");
}

static void rk4_step_definition(void) {
  if (sdt_model_tree6(&g_model) != SD_OK) return;
  int n = g_model.ndof, nb = g_model.nbody;
  sd_real q[SDT_MAXN], qd[SDT_MAXN], tau[SDT_MAXN], f_ext[6 * SDT_MAXN];
  sd_real kq[4][SDT_MAXN], kqd[4][SDT_MAXN], qs[SDT_MAXN], qds[SDT_MAXN];
  sd_real q1[SDT_MAXN], qd1[SDT_MAXN];
  const sd_real dt = SD_R(0.02);
  unsigned seed = 32;
  random_state(&seed, n, q, qd, tau);
  sdt_random_vector(&seed, -2, 2, 6 * nb, f_ext, NULL);
  memset(&g_data, 0, sizeof g_data);
  // the classical tableau: stages at 0, dt/2, dt/2, dt; weights 1 2 2 1 over 6
  const sd_real at[4] = {SD_R(0.0), SD_R(0.5), SD_R(0.5), SD_R(1.0)};
  for (int s = 0; s < 4; s++) {
    for (int k = 0; k < n; k++) {
      qs[k] = s ? q[k] + at[s] * dt * kq[s - 1][k] : q[k];
      qds[k] = s ? qd[k] + at[s] * dt * kqd[s - 1][k] : qd[k];
      kq[s][k] = qds[k];
    }
    sd_forward(&g_model, &g_data, qs, qds, tau, f_ext, kqd[s]);
  }
  for (int k = 0; k < n; k++) {
    q1[k] = q[k] + dt / 6 * (kq[0][k] + 2 * kq[1][k] + 2 * kq[2][k] + kq[3][k]);
    qd1[k] = qd[k] + dt / 6 * (kqd[0][k] + 2 * kqd[1][k] + 2 * kqd[2][k] + kqd[3][k]);
  }
  sd_step(&g_model, &g_data, q, qd, tau, f_ext, dt, SD_RK4);
  EXPECT_LE(sdt_maxdiff(q, q1, n), 100 * SDT_REL, "RK4 step = the classical tableau (q)");
  EXPECT_LE(sdt_maxdiff(qd, qd1, n), 100 * SDT_REL * (1 + sdt_maxabs(kqd[0], n)),
            "RK4 step = the classical tableau with f_ext held constant (qd)");
}

static void zero_step_keeps_state(void) {
  if (sdt_model_chain3(&g_model) != SD_OK) return;
  int n = g_model.ndof;
  sd_real q[SDT_MAXN], qd[SDT_MAXN], tau[SDT_MAXN], q0[SDT_MAXN], qd0[SDT_MAXN];
  unsigned seed = 33;
  random_state(&seed, n, q, qd, tau);
  memcpy(q0, q, sizeof q0);
  memcpy(qd0, qd, sizeof qd0);
  memset(&g_data, 0, sizeof g_data);
  for (int integrator = SD_RK4; integrator <= SD_EULER; integrator++) {
    sd_step(&g_model, &g_data, q, qd, tau, NULL, SD_R(0.0), integrator);
    sdt_context("integrator %d", integrator);
    EXPECT_LE(sdt_maxdiff(q, q0, n) + sdt_maxdiff(qd, qd0, n), 0, "dt = 0 leaves the state as is");
  }
}

// mechanical energy of the passive model at (q, qd)
static double energy(const sd_model* m, const sd_real* q, const sd_real* qd) {
  static sdt_kin kin;
  double qx[SDT_MAXN], qdx[SDT_MAXN];
  for (int k = 0; k < m->ndof; k++) {
    qx[k] = (double)q[k];
    qdx[k] = (double)qd[k];
  }
  sdt_kinematics(m, qx, qdx, &kin);
  return sdt_kinetic_energy(m, &kin) + sdt_potential_energy(m, &kin);
}

static void rk4_conserves_energy(void) {
  // no torque, no friction: gravity alone moves the model and T + V stays constant
#ifdef SD_SINGLE
  const double tol = 1e-4;   // 1000 steps of float rounding
#else
  const double tol = 1e-6;   // RK4 truncation at 1 ms over 1 s; measured 4e-9 and 1.6e-7
#endif
  for (int model = 0; model < SDT_NMODEL; model++) {
    const char* name;
    if (sdt_model_by_index(&g_model, model, &name) != SD_OK) continue;
    int n = g_model.ndof;
    sd_real q[SDT_MAXN], qd[SDT_MAXN], tau[SDT_MAXN];
    unsigned seed = 34;
    gentle_state(&seed, n, q, qd);
    memset(tau, 0, sizeof tau);
    memset(&g_data, 0, sizeof g_data);
    double e0 = energy(&g_model, q, qd), worst = 0;
    static sdt_kin kin;
    double zero[SDT_MAXN] = {0}, qx[SDT_MAXN] = {0};
    sdt_kinematics(&g_model, qx, zero, &kin);
    double scale = fabs(e0) + fabs(sdt_potential_energy(&g_model, &kin)) + 1;
    for (int step = 0; step < 1000; step++) {
      sd_step(&g_model, &g_data, q, qd, tau, NULL, SD_R(0.001), SD_RK4);
      worst = fmax(worst, fabs(energy(&g_model, q, qd) - e0));
    }
    sdt_context("model %s, energy %.6g J", name, e0);
    EXPECT_LE(worst / scale, tol, "RK4 keeps the energy of a passive model (relative drift)");
    EXPECT_INT(g_data.warning[SD_WARN_NONFINITE] + g_data.warning[SD_WARN_SINGULAR], 0,
               "a passive motion raises no warning");
  }
}

#ifndef SD_SINGLE
// error at t = 0.4 s of a run with time step dt against a fine RK4 reference
static double run_error(const sd_real* q0, const sd_real* qd0, const sd_real* tau, sd_real dt,
                        int integrator, const sd_real* q_ref) {
  sd_real q[SDT_MAXN], qd[SDT_MAXN];
  int n = g_model.ndof;
  memcpy(q, q0, (size_t)n * sizeof(sd_real));
  memcpy(qd, qd0, (size_t)n * sizeof(sd_real));
  int steps = (int)(0.4 / dt + 0.5);
  for (int s = 0; s < steps; s++) sd_step(&g_model, &g_data, q, qd, tau, NULL, dt, integrator);
  return q_ref ? sdt_maxdiff(q, q_ref, n) : 0;
}

static void convergence_order(void) {
  // halving dt divides the global error by 2^order: 16 for RK4, 2 for Euler
  if (sdt_model_chain3(&g_model) != SD_OK) return;
  int n = g_model.ndof;
  sd_real q0[SDT_MAXN], qd0[SDT_MAXN], tau[SDT_MAXN], q_ref[SDT_MAXN], qd_ref[SDT_MAXN];
  unsigned seed = 35;
  gentle_state(&seed, n, q0, qd0);
  sdt_random_vector(&seed, -0.5, 0.5, n, tau, NULL);
  memset(&g_data, 0, sizeof g_data);
  memcpy(q_ref, q0, sizeof q_ref);
  memcpy(qd_ref, qd0, sizeof qd_ref);
  for (int s = 0; s < 3200; s++) sd_step(&g_model, &g_data, q_ref, qd_ref, tau, NULL, 0.4 / 3200, SD_RK4);
  double rk_coarse = run_error(q0, qd0, tau, 0.004, SD_RK4, q_ref);
  double rk_fine = run_error(q0, qd0, tau, 0.002, SD_RK4, q_ref);
  double eu_coarse = run_error(q0, qd0, tau, 0.0002, SD_EULER, q_ref);
  double eu_fine = run_error(q0, qd0, tau, 0.0001, SD_EULER, q_ref);
  sdt_context("RK4 errors %.3g and %.3g rad", rk_coarse, rk_fine);
  EXPECT_NEAR(rk_coarse / rk_fine, 16, 4, "RK4 is fourth order: error ratio 2^4 when dt halves");
  sdt_context("Euler errors %.3g and %.3g rad", eu_coarse, eu_fine);
  EXPECT_NEAR(eu_coarse / eu_fine, 2, 0.3, "explicit Euler is first order: error ratio 2");
}
#endif

const sdt_test sdt_integrate_tests[] = {
  {"euler_step_definition", euler_step_definition},
  {"rk4_step_definition", rk4_step_definition},
  {"zero_step_keeps_state", zero_step_keeps_state},
  {"rk4_conserves_energy", rk4_conserves_energy},
#ifndef SD_SINGLE
  // float rounding (1e-7) hides the truncation error the order test measures
  {"convergence_order", convergence_order},
#endif
  {0, 0},
};
