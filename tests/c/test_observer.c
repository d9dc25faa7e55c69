// test_observer.c: the momentum terms (sd_momentum) against the reference mechanics of
// fixtures.c, which share no code with the core: p = dT/dqd, C' qd = dT/dq (with M' = C + C'),
// g = dU/dq, each by central differences of the energies in double; and the observer's residual
// against a known external wrench on the exact plant (sd_step).
#include <math.h>
#include <string.h>

#include "fixtures.h"
#include "harness.h"

static sd_model g_model;
static sd_data g_data;

static double energy(const sd_model* m, const double* q, const double* qd, int potential) {
  static sdt_kin kin;
  sdt_kinematics(m, q, qd, &kin);
  return potential ? sdt_potential_energy(m, &kin) : sdt_kinetic_energy(m, &kin);
}

// d(energy)/dx_k, x = q (wrt_q) or qd, by a central difference
static double gradient(const sd_model* m, double* q, double* qd, int k, int wrt_q, int potential) {
  const double h = 1e-5;
  double* x = wrt_q ? q : qd;
  double save = x[k];
  x[k] = save + h;
  double up = energy(m, q, qd, potential);
  x[k] = save - h;
  double down = energy(m, q, qd, potential);
  x[k] = save;
  return (up - down) / (2 * h);
}

static void momentum_terms_are_energy_gradients(void) {
  unsigned seed = 31;
  for (int index = 0; index < SDT_NMODEL; index++) {
    const char* name;
    if (sdt_model_by_index(&g_model, index, &name) != SD_OK) return;
    const int n = g_model.ndof;
    for (int k = 0; k < n; k++) g_model.dof_armature[k] = (sd_real)(0.01 * (k + 1));
    for (int trial = 0; trial < 5; trial++) {
      sd_real q[SDT_MAXN], qd[SDT_MAXN], p[SDT_MAXN], g[SDT_MAXN], ct[SDT_MAXN];
      sd_real p_ref[SDT_MAXN], g_ref[SDT_MAXN], ct_ref[SDT_MAXN];
      double dq[SDT_MAXN], dqd[SDT_MAXN];
      sdt_random_vector(&seed, -SDT_QMAX, SDT_QMAX, n, q, dq);
      sdt_random_vector(&seed, -2, 2, n, qd, dqd);
      sd_momentum(&g_model, &g_data, q, qd, p, g, ct);
      for (int k = 0; k < n; k++) {
        // the armature's kinetic energy, 1/2 armature qd^2, is not in the reference's
        p_ref[k] = (sd_real)(gradient(&g_model, dq, dqd, k, 0, 0) +
                             (double)g_model.dof_armature[k] * dqd[k]);
        ct_ref[k] = (sd_real)gradient(&g_model, dq, dqd, k, 1, 0);
        g_ref[k] = (sd_real)gradient(&g_model, dq, dqd, k, 1, 1);
      }
      sdt_context("model %s, trial %d", name, trial);
      EXPECT_LE(sdt_maxdiff(p, p_ref, n), SDT_TOL_FD * (1 + sdt_maxabs(p_ref, n)),
                "the generalized momentum M qd is dT/dqd");
      EXPECT_LE(sdt_maxdiff(ct, ct_ref, n), SDT_TOL_FD * (1 + sdt_maxabs(ct_ref, n)),
                "C' qd is dT/dq when M' = C + C' (the Christoffel factorization)");
      EXPECT_LE(sdt_maxdiff(g, g_ref, n), SDT_TOL_FD * (1 + sdt_maxabs(g_ref, n)),
                "g is the gradient of the potential energy");
    }
    sdt_model_by_index(&g_model, index, &name);
  }
}

static void residual_follows_a_step_of_external_wrench(void) {
  // the plant is the model itself, motor torque g(q0) held, a wrench on the last body from
  // t = 0: r_k must be (1 - exp(-K t_k)) tau_ext with tau_ext = -(rnea with f_ext - rnea
  // without) at the state, up to how far tau_ext moves as the arm does in 40 ms
  const char* name;
  if (sdt_model_by_index(&g_model, 0, &name) != SD_OK) return;
  const int n = g_model.ndof, nb = g_model.nbody;
  static sd_observer_config c;
  static sd_observer_state s;
  memset(&c, 0, sizeof c);
  c.dt = SD_R(1e-3);
  for (int k = 0; k < n; k++) c.gain[k] = SD_R(50);
  EXPECT_INT(sd_observer_check(&g_model, &c), SD_OBSERVER_OK, "a valid configuration is accepted");
  sd_real q[SDT_MAXN], qd[SDT_MAXN], tau[SDT_MAXN], zero[SDT_MAXN], f_ext[6 * SDT_MAXN];
  sd_real t_free[SDT_MAXN], t_push[SDT_MAXN], p[SDT_MAXN], g[SDT_MAXN], ct[SDT_MAXN];
  memset(zero, 0, sizeof zero);
  memset(qd, 0, sizeof qd);
  memset(f_ext, 0, sizeof f_ext);
  for (int k = 0; k < n; k++) q[k] = SD_R(0.3) * (sd_real)(k % 3) - SD_R(0.2);
  f_ext[6 * (nb - 1) + 3] = SD_R(2);       // 2 N along the last body's x
  f_ext[6 * (nb - 1) + 1] = SD_R(0.1);     // 0.1 N m about its y
  sd_momentum(&g_model, &g_data, q, qd, p, g, ct);
  memcpy(tau, g, sizeof tau);
  sd_observer_reset(&g_model, &g_data, &c, &s, q, qd);
  sd_rnea(&g_model, &g_data, q, zero, zero, NULL, t_free);
  sd_rnea(&g_model, &g_data, q, zero, zero, f_ext, t_push);
  double worst = 0, scale = 0;
  for (int tick = 1; tick <= 40; tick++) {
    for (int sub = 0; sub < 4; sub++) sd_step(&g_model, &g_data, q, qd, tau, f_ext, c.dt / 4, SD_RK4);
    sd_observer_step(&g_model, &g_data, &c, &s, q, qd, tau);
    double rise = 1 - exp(-50.0 * 1e-3 * tick);
    for (int k = 0; k < n; k++) {
      double ext = -(double)(t_push[k] - t_free[k]);
      worst = fmax(worst, fabs((double)s.r[k] - rise * ext));
      scale = fmax(scale, fabs(ext));
    }
  }
  sdt_context("model %s", name);
  EXPECT_INT(s.tick, 40, "every sample was taken");
  EXPECT_LE(worst, 0.02 * scale, "r rises as K/(s+K) of the external torque (the arm moves a little)");
}

static void bad_configurations_are_refused(void) {
  const char* name;
  if (sdt_model_by_index(&g_model, 0, &name) != SD_OK) return;
  static sd_observer_config c;
  memset(&c, 0, sizeof c);
  EXPECT_INT(sd_observer_check(&g_model, &c), SD_OBSERVER_ERR_PERIOD, "dt = 0 is refused");
  c.dt = SD_R(1e-3);
  c.gain[0] = SD_R(-1);
  EXPECT_INT(sd_observer_check(&g_model, &c), SD_OBSERVER_ERR_GAIN, "a negative gain is refused");
  c.gain[0] = SD_R(50);
  c.friction_coulomb[1] = SD_R(0.1);
  EXPECT_INT(sd_observer_check(&g_model, &c), SD_OBSERVER_ERR_FRICTION,
             "Coulomb friction needs a smoothing speed");
}

const sdt_test sdt_observer_tests[] = {
  {"momentum_terms_are_energy_gradients", momentum_terms_are_energy_gradients},
  {"residual_follows_a_step_of_external_wrench", residual_follows_a_step_of_external_wrench},
  {"bad_configurations_are_refused", bad_configurations_are_refused},
  {0, 0},
};
