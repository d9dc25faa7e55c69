// test_regressor.c: the joint-torque regressor (sd_regressor) against the core's own inverse
// dynamics: Y(q, qd, qdd) pi + armature qdd = sd_rnea(q, qd, qdd), pi read from the model.
#include <math.h>
#include <string.h>

#include "fixtures.h"
#include "harness.h"

static sd_model g_model;
static sd_data g_data;
static sd_real g_Y[SDT_MAXN * SD_NPARAM * SDT_MAXN];

// the model's parameters in the regressor's order: m, h, I about the origin (xx xy yy xz yz zz)
static void parameters(const sd_model* m, double* pi) {
  for (int i = 0; i < m->nbody; i++) {
    const sd_real* I = m->body_inertia0[i];     // xx yy zz xy xz yz
    double* p = pi + SD_NPARAM * i;
    p[0] = (double)m->body_mass[i];
    for (int k = 0; k < 3; k++) p[1 + k] = (double)m->body_mcom[i][k];
    p[4] = (double)I[0]; p[5] = (double)I[3]; p[6] = (double)I[1];
    p[7] = (double)I[4]; p[8] = (double)I[5]; p[9] = (double)I[2];
  }
}

static void regressor_times_parameters_is_rnea(void) {
  unsigned seed = 23;
  for (int index = 0; index < SDT_NMODEL; index++) {
    const char* name;
    if (sdt_model_by_index(&g_model, index, &name) != SD_OK) return;
    const int n = g_model.ndof, ncol = SD_NPARAM * g_model.nbody;
    double pi[SD_NPARAM * SDT_MAXN];
    parameters(&g_model, pi);
    for (int trial = 0; trial < 20; trial++) {
      sd_real q[SD_MAX_Q], qd[SDT_MAXN], qdd[SDT_MAXN], tau[SDT_MAXN];
      double dq[SD_MAX_Q], dqd[SDT_MAXN], dqdd[SDT_MAXN];
      sdt_random_vector(&seed, -SDT_QMAX, SDT_QMAX, g_model.nq, q, dq);
      sdt_random_vector(&seed, -2, 2, n, qd, dqd);
      sdt_random_vector(&seed, -5, 5, n, qdd, dqdd);
      sd_normalize_q(&g_model, q);
      sd_rnea(&g_model, &g_data, q, qd, qdd, NULL, tau);
      sd_regressor(&g_model, &g_data, q, qd, qdd, g_Y);
      double worst = 0, scale = 1;
      for (int j = 0; j < n; j++) {
        double sum = (double)g_model.dof_armature[j] * (double)qdd[j];
        for (int c = 0; c < ncol; c++) sum += (double)g_Y[j * ncol + c] * pi[c];
        worst = fmax(worst, fabs(sum - (double)tau[j]));
        scale = fmax(scale, fabs((double)tau[j]));
      }
      sdt_context("model %s, trial %d", name, trial);
      EXPECT_LE(worst, 10 * SDT_REL * scale, "Y pi + armature qdd is the RNEA's torque");
    }
  }
}

static void bodies_act_only_on_their_ancestors(void) {
  // tree6 has two roots and a branch: a body's columns are zero in the rows of the dofs that
  // are not between it and the base
  const char* name;
  if (sdt_model_by_index(&g_model, 1, &name) != SD_OK) return;
  unsigned seed = 5;
  sd_real q[SD_MAX_Q], qd[SDT_MAXN], qdd[SDT_MAXN];
  double dq[SD_MAX_Q], dqd[SDT_MAXN], dqdd[SDT_MAXN];
  sdt_random_vector(&seed, -1, 1, g_model.nq, q, dq);
  sdt_random_vector(&seed, -1, 1, g_model.ndof, qd, dqd);
  sdt_random_vector(&seed, -1, 1, g_model.ndof, qdd, dqdd);
  sd_normalize_q(&g_model, q);
  sd_regressor(&g_model, &g_data, q, qd, qdd, g_Y);
  const int ncol = SD_NPARAM * g_model.nbody;
  int stray = 0;
  for (int i = 0; i < g_model.nbody; i++) {
    for (int k = 0; k < g_model.nbody; k++) {
      int ancestor = 0;
      for (int a = i; a >= 0; a = g_model.body_parent[a]) ancestor |= (a == k);
      for (int j = g_model.body_dofadr[k]; !ancestor && j < g_model.body_dofadr[k] + g_model.body_dofnum[k]; j++)
        for (int c = 0; c < SD_NPARAM; c++) stray += g_Y[j * ncol + SD_NPARAM * i + c] != 0;
    }
  }
  sdt_context("model %s", name);
  EXPECT_INT(stray, 0, "a body's parameters reach only the dofs between it and the base");
}

const sdt_test sdt_regressor_tests[] = {
  {"regressor_times_parameters_is_rnea", regressor_times_parameters_is_rnea},
  {"bodies_act_only_on_their_ancestors", bodies_act_only_on_their_ancestors},
  {0, 0},
};
