// test_control.c: the closed-form controller step (sd_control_check, sd_control_reset,
// sd_control_step) against hand computations from sd_rnea and the joint PD law, and in a
// closed loop with sd_step.
#include <math.h>
#include <string.h>

#include "fixtures.h"
#include "harness.h"

// relative tolerance of one torque against its hand computation, and the closed-loop hold
#ifdef SD_SINGLE
#define CTL_REL 1e-4
#define CTL_HOLD_TOL 1e-4
#else
#define CTL_REL 1e-12
#define CTL_HOLD_TOL 1e-9
#endif

static sd_model g_model;
static sd_data g_data;       // the controller's
static sd_data g_ref;        // the hand computations' (no state shared with the controller)
static sd_control_config g_cfg;
static sd_control_state g_state;

// a configuration of one mode with distinct gains per dof, so a wrong index shows
static void configure(sd_control_config* c, const sd_model* m, int mode, int update_ticks,
                      unsigned seed) {
  memset(c, 0, sizeof *c);
  c->mode = mode;
  c->update_ticks = update_ticks;
  for (int j = 0; j < m->ndof; j++) {
    c->kp[j] = (sd_real)sdt_uniform(&seed, 5, 50);
    c->kd[j] = (sd_real)sdt_uniform(&seed, 0.5, 5);
    c->tau_max[j] = SD_R(0.0);   // no limit
  }
}

// the desired and measured states of a model
typedef struct ctl_states_ {
  sd_real q_d[SD_MAX_Q], qd_d[SDT_MAXN], qdd_d[SDT_MAXN], q[SD_MAX_Q], qd[SDT_MAXN];
} ctl_states;

static void random_states(unsigned* seed, const sd_model* m, ctl_states* s) {
  sdt_random_vector(seed, -SDT_QMAX, SDT_QMAX, m->nq, s->q_d, NULL);
  sdt_random_vector(seed, -2, 2, m->ndof, s->qd_d, NULL);
  sdt_random_vector(seed, -4, 4, m->ndof, s->qdd_d, NULL);
  sdt_random_vector(seed, -SDT_QMAX, SDT_QMAX, m->nq, s->q, NULL);
  sdt_random_vector(seed, -2, 2, m->ndof, s->qd, NULL);
}

static void step(const ctl_states* s, sd_real* tau) {
  sd_control_step(&g_model, &g_data, &g_cfg, &g_state, s->q_d, s->qd_d, s->qdd_d, s->q, s->qd,
                  tau);
}

// kp e + kd e' of every dof in double, for a model whose q addresses equal its dof addresses
static void pd_torque(const sd_model* m, const sd_control_config* c, const ctl_states* s,
                      double* pd) {
  for (int j = 0; j < m->ndof; j++) {
    double e = (double)s->q_d[j] - (double)s->q[j], de = (double)s->qd_d[j] - (double)s->qd[j];
    pd[j] = (double)c->kp[j] * e + (double)c->kd[j] * de;
  }
}

//---------------------------------- sd_control_check --------------------------------------------

#define CHECK_REJECTS(mutation, code, reason)                             \
  do {                                                                   \
    configure(&g_cfg, &g_model, SD_MODE_FEEDFORWARD_PD, 10, 1);          \
    mutation;                                                            \
    sdt_context("%s", #mutation);                                        \
    EXPECT_INT(sd_control_check(&g_model, &g_cfg), code, reason);        \
  } while (0)

static void check_accepts_good_configs(void) {
  for (int model = 0; model < SDT_NMODEL; model++) {
    const char* name;
    if (sdt_model_by_index(&g_model, model, &name) != SD_OK) continue;
    for (int mode = 0; mode < SD_NMODE; mode++) {
      configure(&g_cfg, &g_model, mode, mode == 0 ? 1 : 10, 2);
      g_cfg.tau_max[0] = SD_R(3.0);
      g_cfg.kp[g_model.ndof - 1] = SD_R(0.0);   // zero gains and zero limits are allowed
      g_cfg.kd[g_model.ndof - 1] = SD_R(0.0);
      sdt_context("model %s, mode %d", name, mode);
      EXPECT_INT(sd_control_check(&g_model, &g_cfg), SD_CONTROL_OK,
                 "every mode, update_ticks >= 1, gains and limits >= 0 (0: none) are accepted");
    }
  }
}

static void check_rejects_bad_configs(void) {
  if (sdt_model_chain3(&g_model) != SD_OK) return;
  int last = g_model.ndof - 1;
  CHECK_REJECTS(g_cfg.mode = -1, SD_CONTROL_ERR_MODE,
                "a mode below SD_MODE_FEEDFORWARD is rejected");
  CHECK_REJECTS(g_cfg.mode = SD_NMODE, SD_CONTROL_ERR_MODE, "SD_NMODE is not a mode");
  CHECK_REJECTS(g_cfg.update_ticks = 0, SD_CONTROL_ERR_UPDATE,
                "inverse dynamics need at least one small step per update");
  CHECK_REJECTS(g_cfg.update_ticks = -3, SD_CONTROL_ERR_UPDATE,
                "a negative update period is rejected");
  CHECK_REJECTS(g_cfg.kp[last] = SD_R(-1.0), SD_CONTROL_ERR_GAIN,
                "a negative kp would push the error up");
  CHECK_REJECTS(g_cfg.kd[0] = SD_R(-0.1), SD_CONTROL_ERR_GAIN,
                "a negative kd would pump energy in");
  CHECK_REJECTS(g_cfg.tau_max[2] = SD_R(-2.0), SD_CONTROL_ERR_LIMIT,
                "a negative torque limit is meaningless");
  CHECK_REJECTS(g_cfg.kp[1] = (sd_real)NAN, SD_CONTROL_ERR_GAIN, "a NaN kp is rejected");
  CHECK_REJECTS(g_cfg.kd[last] = (sd_real)NAN, SD_CONTROL_ERR_GAIN, "a NaN kd is rejected");
  CHECK_REJECTS(g_cfg.tau_max[0] = (sd_real)NAN, SD_CONTROL_ERR_LIMIT,
                "a NaN torque limit is rejected");
  CHECK_REJECTS(g_cfg.kp[0] = (sd_real)INFINITY, SD_CONTROL_ERR_GAIN,
                "an infinite gain is rejected");
  CHECK_REJECTS(g_cfg.tau_max[last] = (sd_real)INFINITY, SD_CONTROL_ERR_LIMIT,
                "an infinite limit is rejected (0 means none)");
  CHECK_REJECTS(g_cfg.error_lowpass[1] = SD_R(1.5), SD_CONTROL_ERR_FILTER,
                "a low-pass coefficient over 1 would overshoot the measured error");
  CHECK_REJECTS(g_cfg.error_lowpass[0] = SD_R(-0.1), SD_CONTROL_ERR_FILTER,
                "a negative low-pass coefficient would run away from the measured error");
  CHECK_REJECTS(g_cfg.error_lowpass[last] = (sd_real)NAN, SD_CONTROL_ERR_FILTER,
                "a NaN low-pass coefficient is rejected");
}

static void check_codes_have_messages(void) {
  static const int codes[] = {SD_CONTROL_ERR_MODE, SD_CONTROL_ERR_UPDATE, SD_CONTROL_ERR_BALL,
                              SD_CONTROL_ERR_GAIN, SD_CONTROL_ERR_LIMIT, SD_CONTROL_ERR_FILTER,
                              SD_CONTROL_ERR_FRICTION};
  const int n = (int)(sizeof codes / sizeof codes[0]);
  const char* unknown = sd_control_strerror(-100);
  for (int k = 0; k < n; k++) {
    sdt_context("code %d", codes[k]);
    EXPECT_INT(codes[k] < 0, 1, "a fault is a negative code, SD_CONTROL_OK (0) is not one");
    EXPECT_INT(strcmp(sd_control_strerror(codes[k]), unknown) != 0, 1,
               "every fault names itself, so a caller can say which check failed");
    for (int l = 0; l < k; l++) {
      EXPECT_INT(codes[k] != codes[l] && strcmp(sd_control_strerror(codes[k]),
                                                sd_control_strerror(codes[l])) != 0, 1,
                 "no two faults share a code or a message");
    }
  }
}

static void check_rejects_ball_joints(void) {
  for (int model = 0; model < SDT_NMODEL; model++) {
    const char* name;
    if (sdt_model_by_index(&g_model, model, &name) != SD_OK) continue;
    // body 0 of both fixtures has a 3-dof joint: make it a ball joint
    g_model.body_ball[0] = 1;
    int bad = -2;
    int code = sd_model_setup(&g_model, &bad);
    sdt_context("model %s, body 0 a ball joint", name);
    EXPECT_INT(code, SD_OK, "a 3-dof joint may be a ball joint: the model itself is valid");
    EXPECT_INT(g_model.nq, g_model.ndof + 1, "the ball's quaternion takes one coordinate more");
    configure(&g_cfg, &g_model, SD_MODE_FEEDFORWARD_PD, 10, 3);
    EXPECT_INT(sd_control_check(&g_model, &g_cfg), SD_CONTROL_ERR_BALL,
               "the joint PD works on angles: a model with a ball joint is rejected");
  }
}

//---------------------------------- feed-forward ------------------------------------------------

static void feedforward_is_rnea_held(void) {
  const int U = 5;
  unsigned seed = 41;
  for (int model = 0; model < SDT_NMODEL; model++) {
    const char* name;
    if (sdt_model_by_index(&g_model, model, &name) != SD_OK) continue;
    int n = g_model.ndof;
    // nonzero gains: feed-forward mode must ignore them
    configure(&g_cfg, &g_model, SD_MODE_FEEDFORWARD, U, 4);
    EXPECT_INT(sd_control_check(&g_model, &g_cfg), SD_CONTROL_OK, "a valid configuration");
    memset(&g_data, 0, sizeof g_data);
    memset(&g_ref, 0, sizeof g_ref);
    sd_control_reset(&g_state);
    for (int period = 0; period < 3; period++) {
      ctl_states s;
      sd_real tau[SDT_MAXN], ref[SDT_MAXN], held[SDT_MAXN];
      random_states(&seed, &g_model, &s);
      sd_rnea(&g_model, &g_ref, s.q_d, s.qd_d, s.qdd_d, NULL, ref);
      step(&s, tau);
      sdt_context("model %s, tick %d", name, period * U);
      EXPECT_LE(sdt_maxdiff(tau, ref, n), 0,
                "on an update tick tau = rnea(q_d, qd_d, qdd_d), bit for bit");
      EXPECT_LE(sdt_maxdiff(g_state.tau_hold, ref, n), 0, "and the state holds it");
      EXPECT_INT(g_state.status, 0, "no limit, no fault");
      memcpy(held, tau, sizeof held);
      double largest_change = 0;
      for (int t = 1; t < U; t++) {
        // the desired and the measured state both move: nothing may reach tau
        sd_real before[SDT_MAXN];
        memcpy(before, s.q_d, sizeof before);
        random_states(&seed, &g_model, &s);
        largest_change = fmax(largest_change, sdt_maxdiff(before, s.q_d, n));
        step(&s, tau);
        sdt_context("model %s, tick %d", name, period * U + t);
        EXPECT_LE(sdt_maxdiff(tau, held, n), 0,
                  "between updates the feed-forward torque is held (zero-order hold)");
      }
      EXPECT_GE(largest_change, 0.1, "the held ticks did see a different desired state");
      EXPECT_INT(g_state.tick, (period + 1) * U, "one tick per small step");
    }
    // the next update really recomputes: different states give different torques
    ctl_states s;
    sd_real tau[SDT_MAXN], ref[SDT_MAXN], held[SDT_MAXN];
    memcpy(held, g_state.tau_hold, sizeof held);
    random_states(&seed, &g_model, &s);
    sd_rnea(&g_model, &g_ref, s.q_d, s.qd_d, s.qdd_d, NULL, ref);
    step(&s, tau);
    sdt_context("model %s, tick %d", name, 3 * U);
    EXPECT_LE(sdt_maxdiff(tau, ref, n), 0, "tick update_ticks * k recomputes rnea at the new state");
    EXPECT_GE(sdt_maxdiff(tau, held, n), 1e-3, "and the recomputed torque differs from the held");
    EXPECT_INT(g_state.nlimited + g_state.nfault, 0, "no limit, no fault in the whole run");
  }
}

static void feedforward_pd_adds_joint_pd(void) {
  const int U = 4;
  unsigned seed = 42;
  for (int model = 0; model < SDT_NMODEL; model++) {
    const char* name;
    if (sdt_model_by_index(&g_model, model, &name) != SD_OK) continue;
    int n = g_model.ndof;
    configure(&g_cfg, &g_model, SD_MODE_FEEDFORWARD_PD, U, 5);
    memset(&g_data, 0, sizeof g_data);
    memset(&g_ref, 0, sizeof g_ref);
    sd_control_reset(&g_state);
    sd_real held[SDT_MAXN];
    for (int t = 0; t < 2 * U + 1; t++) {
      ctl_states s;
      sd_real tau[SDT_MAXN];
      double pd[SDT_MAXN];
      random_states(&seed, &g_model, &s);
      if (t % U == 0) sd_rnea(&g_model, &g_ref, s.q_d, s.qd_d, s.qdd_d, NULL, held);
      pd_torque(&g_model, &g_cfg, &s, pd);
      step(&s, tau);
      sdt_context("model %s, tick %d", name, t);
      for (int j = 0; j < n; j++) {
        double expect = (double)held[j] + pd[j];
        EXPECT_NEAR(tau[j], expect, CTL_REL * (fabs((double)held[j]) + fabs(pd[j]) + 1),
                    "feed-forward + PD: tau = held rnea(desired) + kp e + kd e' every small step");
      }
    }
  }
}

//---------------------------------- computed torque ---------------------------------------------

static void computed_torque_is_rnea_at_measured_state(void) {
  const int U = 3;
  unsigned seed = 43;
  for (int model = 0; model < SDT_NMODEL; model++) {
    const char* name;
    if (sdt_model_by_index(&g_model, model, &name) != SD_OK) continue;
    int n = g_model.ndof;
    configure(&g_cfg, &g_model, SD_MODE_COMPUTED_TORQUE, U, 6);
    memset(&g_data, 0, sizeof g_data);
    memset(&g_ref, 0, sizeof g_ref);
    sd_control_reset(&g_state);
    ctl_states s;
    sd_real tau[SDT_MAXN], ref[SDT_MAXN], acc[SDT_MAXN];

    // measured == desired: no error, the torque of the desired motion
    random_states(&seed, &g_model, &s);
    memcpy(s.q, s.q_d, sizeof s.q);
    memcpy(s.qd, s.qd_d, sizeof s.qd);
    sd_rnea(&g_model, &g_ref, s.q_d, s.qd_d, s.qdd_d, NULL, ref);
    step(&s, tau);
    sdt_context("model %s, measured == desired", name);
    EXPECT_LE(sdt_maxdiff(tau, ref, n), CTL_REL * (1 + sdt_maxabs(ref, n)),
              "with no error computed torque is rnea(desired)");
    for (int t = 1; t < U; t++) step(&s, tau);

    // with an error: rnea at the measured state of qdd_d + kp e + kd e'
    for (int period = 1; period < 4; period++) {
      random_states(&seed, &g_model, &s);
      double pd[SDT_MAXN];
      pd_torque(&g_model, &g_cfg, &s, pd);
      for (int j = 0; j < n; j++) acc[j] = (sd_real)((double)s.qdd_d[j] + pd[j]);
      sd_rnea(&g_model, &g_ref, s.q, s.qd, acc, NULL, ref);
      step(&s, tau);
      sdt_context("model %s, tick %d", name, period * U);
      EXPECT_LE(sdt_maxdiff(tau, ref, n), CTL_REL * (1 + sdt_maxabs(ref, n)),
                "computed torque: tau = rnea(q, qd, qdd_d + kp e + kd e')");
      // held, and no PD added on top between updates
      memcpy(ref, tau, sizeof ref);
      for (int t = 1; t < U; t++) {
        random_states(&seed, &g_model, &s);
        step(&s, tau);
        sdt_context("model %s, tick %d", name, period * U + t);
        EXPECT_LE(sdt_maxdiff(tau, ref, n), 0,
                  "computed torque is held between updates, with no PD on top");
      }
    }
  }
}

//---------------------------------- PD ----------------------------------------------------------

static void pd_mode_has_no_inverse_dynamics(void) {
  unsigned seed = 44;
  for (int model = 0; model < SDT_NMODEL; model++) {
    const char* name;
    if (sdt_model_by_index(&g_model, model, &name) != SD_OK) continue;
    int n = g_model.ndof;
    configure(&g_cfg, &g_model, SD_MODE_PD, 3, 7);
    memset(&g_data, 0, sizeof g_data);
    memset(&g_ref, 0, sizeof g_ref);
    sd_control_reset(&g_state);
    ctl_states s;
    sd_real tau[SDT_MAXN], g[SDT_MAXN], zero[SDT_MAXN];
    memset(zero, 0, sizeof zero);

    // at rest on target in a pose where gravity pulls: the PD alone gives nothing
    random_states(&seed, &g_model, &s);
    memcpy(s.q, s.q_d, sizeof s.q);
    memset(s.qd_d, 0, sizeof s.qd_d);
    memset(s.qd, 0, sizeof s.qd);
    sd_rnea(&g_model, &g_ref, s.q, zero, zero, NULL, g);
    step(&s, tau);
    sdt_context("model %s, on target at rest", name);
    EXPECT_GE(sdt_maxabs(g, n), 0.1, "gravity does load this pose");
    EXPECT_LE(sdt_maxabs(tau, n), 0, "PD mode does not compensate gravity: tau = 0 with no error");

    for (int t = 1; t < 7; t++) {
      double pd[SDT_MAXN];
      random_states(&seed, &g_model, &s);
      pd_torque(&g_model, &g_cfg, &s, pd);
      step(&s, tau);
      sdt_context("model %s, tick %d", name, t);
      for (int j = 0; j < n; j++) {
        EXPECT_NEAR(tau[j], pd[j], CTL_REL * (fabs(pd[j]) + 1),
                    "PD mode: tau = kp e + kd e', no inverse dynamics");
      }
    }
  }
}

// the errors the gains act on through their one-pole low-pass: the first step after a reset
// starts it at the measured errors, each later one moves it the coefficient's share of the way
static void pd_acts_on_lowpassed_errors(void) {
  unsigned seed = 47;
  for (int model = 0; model < SDT_NMODEL; model++) {
    const char* name;
    if (sdt_model_by_index(&g_model, model, &name) != SD_OK || g_model.free_root) continue;
    int n = g_model.ndof;
    configure(&g_cfg, &g_model, SD_MODE_PD, 3, 8);
    for (int j = 0; j < n; j++) g_cfg.error_lowpass[j] = (sd_real)(0.05 + 0.1 * j);
    memset(&g_data, 0, sizeof g_data);
    EXPECT_INT(sd_control_check(&g_model, &g_cfg), SD_CONTROL_OK, "coefficients in [0, 1] are accepted");
    ctl_states s;
    sd_real tau[SDT_MAXN];
    double e[SDT_MAXN], de[SDT_MAXN];
    for (int round = 0; round < 2; round++) {     // a reset starts the filter over
      sd_control_reset(&g_state);
      for (int t = 0; t < 5; t++) {
        random_states(&seed, &g_model, &s);
        step(&s, tau);
        sdt_context("model %s, round %d, tick %d", name, round, t);
        for (int j = 0; j < n; j++) {
          double a = t == 0 ? 1.0 : (double)g_cfg.error_lowpass[j];
          double e_now = (double)s.q_d[j] - (double)s.q[j], de_now = (double)s.qd_d[j] - (double)s.qd[j];
          e[j] = t == 0 ? e_now : e[j] + a * (e_now - e[j]);
          de[j] = t == 0 ? de_now : de[j] + a * (de_now - de[j]);
          double expect = (double)g_cfg.kp[j] * e[j] + (double)g_cfg.kd[j] * de[j];
          EXPECT_NEAR(tau[j], expect, CTL_REL * (fabs(expect) + 10),
                      "tau = kp e_f + kd e'_f, e_f += a (e - e_f), started at the measured errors");
        }
      }
    }
  }
}

//---------------------------------- limits ------------------------------------------------------

static void limits_clamp_and_count(void) {
  if (sdt_model_chain3(&g_model) != SD_OK) return;
  int n = g_model.ndof;
  unsigned seed = 45;
  sd_control_config free_cfg;
  sd_control_state free_state;
  configure(&g_cfg, &g_model, SD_MODE_FEEDFORWARD_PD, 2, 8);
  free_cfg = g_cfg;   // the same controller without limits
  for (int j = 0; j < n; j++) g_cfg.tau_max[j] = SD_R(0.05);
  EXPECT_INT(sd_control_check(&g_model, &g_cfg), SD_CONTROL_OK, "a valid configuration");
  memset(&g_data, 0, sizeof g_data);
  memset(&g_ref, 0, sizeof g_ref);
  sd_control_reset(&g_state);
  sd_control_reset(&free_state);
  for (int t = 0; t < 4; t++) {
    ctl_states s;
    sd_real tau[SDT_MAXN], raw[SDT_MAXN];
    random_states(&seed, &g_model, &s);
    sd_control_step(&g_model, &g_ref, &free_cfg, &free_state, s.q_d, s.qd_d, s.qdd_d, s.q, s.qd,
                    raw);
    step(&s, tau);
    sdt_context("tick %d, tau_max 0.05 on every dof", t);
    EXPECT_GE(sdt_maxabs(raw, n), 0.5, "the unlimited torque is well beyond the limit");
    for (int j = 0; j < n; j++) {
      double lim = (double)g_cfg.tau_max[j], r = (double)raw[j];
      double expect = r > lim ? lim : r < -lim ? -lim : r;
      EXPECT_NEAR(tau[j], expect, CTL_REL * (fabs(r) + 1),
                  "tau = clamp(unlimited torque, -tau_max, +tau_max)");
    }
    EXPECT_LE(sdt_maxabs(tau, n), g_cfg.tau_max[0], "every torque within +-tau_max");
    EXPECT_INT(g_state.status, SD_STATUS_LIMITED, "a clamp flags SD_STATUS_LIMITED only");
    EXPECT_INT(g_state.nlimited, t + 1, "one limited step counted per step, not per dof");
    EXPECT_INT(g_state.nfault, 0, "limiting is normal operation, not a fault");
  }

  // a limit on one dof only, wide enough elsewhere: only that dof is touched
  ctl_states s;
  sd_real tau[SDT_MAXN], raw[SDT_MAXN];
  random_states(&seed, &g_model, &s);
  sd_control_step(&g_model, &g_ref, &free_cfg, &free_state, s.q_d, s.qd_d, s.qdd_d, s.q, s.qd,
                  raw);
  for (int j = 0; j < n; j++) g_cfg.tau_max[j] = SD_R(0.0);
  int k = 2;
  g_cfg.tau_max[k] = (sd_real)(0.5 * fabs((double)raw[k]));
  step(&s, tau);
  sdt_context("tick 4, tau_max only on dof %d", k);
  EXPECT_NEAR(tau[k], raw[k] > 0 ? g_cfg.tau_max[k] : -g_cfg.tau_max[k], 0,
              "the limited dof is clamped to its limit, with the sign of its torque");
  for (int j = 0; j < n; j++) {
    if (j != k) {
      EXPECT_NEAR(tau[j], raw[j], CTL_REL * (fabs((double)raw[j]) + 1),
                  "tau_max = 0 means no limit: the other dofs are untouched");
    }
  }
  EXPECT_INT(g_state.status, SD_STATUS_LIMITED, "one clamped dof flags the step");
  EXPECT_INT(g_state.nlimited, 5, "and counts it");

  // a limit above every torque: no flag, no count
  for (int j = 0; j < n; j++) g_cfg.tau_max[j] = SD_R(1e6);
  random_states(&seed, &g_model, &s);
  step(&s, tau);
  sdt_context("tick 5, tau_max 1e6");
  EXPECT_INT(g_state.status, 0, "no clamp, no flag");
  EXPECT_INT(g_state.nlimited, 5, "and no count");
}

//---------------------------------- faults ------------------------------------------------------

// which input of the step gets the bad number
enum { BAD_Q, BAD_Q_D, BAD_QD, BAD_QD_D, BAD_QDD_D, NBAD };
static const char* const kBadName[NBAD] = {"q", "q_d", "qd", "qd_d", "qdd_d"};

static void spoil(ctl_states* s, int which, int index, sd_real value) {
  sd_real* v = which == BAD_Q ? s->q : which == BAD_Q_D ? s->q_d : which == BAD_QD ? s->qd
             : which == BAD_QD_D ? s->qd_d : s->qdd_d;
  v[index] = value;
}

static void nonfinite_input_is_a_fault(void) {
  if (sdt_model_tree6(&g_model) != SD_OK) return;
  int n = g_model.ndof;
  const int U = 4;
  unsigned seed = 46;
  sd_control_state twin;   // the same controller, fed finite numbers only
  configure(&g_cfg, &g_model, SD_MODE_FEEDFORWARD_PD, U, 9);
  for (int which = 0; which < NBAD; which++) {
    for (int kind = 0; kind < 2; kind++) {
      sd_real bad = kind ? (sd_real)INFINITY : (sd_real)NAN;
      memset(&g_data, 0, sizeof g_data);
      memset(&g_ref, 0, sizeof g_ref);
      sd_control_reset(&g_state);
      sd_control_reset(&twin);
      ctl_states s;
      sd_real tau[SDT_MAXN], ref[SDT_MAXN], held[SDT_MAXN];
      for (int t = 0; t < 2 * U + 1; t++) {
        random_states(&seed, &g_model, &s);
        sd_control_step(&g_model, &g_ref, &g_cfg, &twin, s.q_d, s.qd_d, s.qdd_d, s.q, s.qd, ref);
        if (t == 2) {
          // a bad number on a tick between updates
          memcpy(held, g_state.tau_hold, sizeof held);
          spoil(&s, which, (3 * which + 1) % n, bad);
          step(&s, tau);
          sdt_context("%s[%d] = %s at tick 2", kBadName[which], (3 * which + 1) % n,
                      kind ? "inf" : "NaN");
          EXPECT_LE(sdt_maxabs(tau, n), 0, "a non-finite input gives zero torque, never NaN");
          EXPECT_INT(g_state.status, SD_STATUS_NONFINITE, "flagged SD_STATUS_NONFINITE");
          EXPECT_INT(g_state.nfault, 1, "and counted as a fault");
          EXPECT_INT(g_state.nlimited, 0, "not as limiting");
          EXPECT_INT(g_state.tick, 3, "the tick still advances");
          EXPECT_LE(sdt_maxdiff(g_state.tau_hold, held, n), 0,
                    "the held torque is untouched by the bad step");
          continue;
        }
        if (t == 3) {
          // the first good step after a fault recomputes the inverse dynamics, as a controller
          // starting afresh on this state does (the skipped update must not linger)
          sd_control_state fresh;
          sd_control_reset(&fresh);
          sd_control_step(&g_model, &g_ref, &g_cfg, &fresh, s.q_d, s.qd_d, s.qdd_d, s.q, s.qd, ref);
        }
        step(&s, tau);
        sdt_context("%s = %s at tick 2, now tick %d", kBadName[which], kind ? "inf" : "NaN", t);
        EXPECT_LE(sdt_maxdiff(tau, ref, n), 0,
                  "after a fault: a fresh inverse dynamics, then the same as a controller that "
                  "never saw the fault from its next update on");
        EXPECT_INT(g_state.status, 0, "a finite step clears the fault flag");
      }
      EXPECT_INT(g_state.nfault, 1, "one fault in the run");
    }
  }

  // a bad number on an update tick: the hold keeps its last finite value, never NaN
  sd_control_reset(&g_state);
  ctl_states s;
  sd_real tau[SDT_MAXN], held[SDT_MAXN];
  random_states(&seed, &g_model, &s);
  for (int t = 0; t < U; t++) step(&s, tau);
  memcpy(held, g_state.tau_hold, sizeof held);
  random_states(&seed, &g_model, &s);
  s.qd[0] = (sd_real)NAN;
  step(&s, tau);
  sdt_context("qd[0] = NaN on update tick %d", U);
  EXPECT_LE(sdt_maxabs(tau, n), 0, "zero torque");
  EXPECT_LE(sdt_maxdiff(g_state.tau_hold, held, n), 0,
            "a fault on an update tick does not reach the held torque");
  EXPECT_INT(g_state.nfault, 1, "counted");
  EXPECT_INT(g_state.tick, U + 1, "the tick advances");
}

//---------------------------------- reset -------------------------------------------------------

static void reset_clears_everything(void) {
  if (sdt_model_chain3(&g_model) != SD_OK) return;
  int n = g_model.ndof;
  unsigned seed = 47;
  configure(&g_cfg, &g_model, SD_MODE_FEEDFORWARD, 3, 10);
  for (int j = 0; j < n; j++) g_cfg.tau_max[j] = SD_R(0.01);
  memset(&g_data, 0, sizeof g_data);
  // fill the state with garbage first: reset must not rely on a zeroed struct
  memset(&g_state, 0x5a, sizeof g_state);
  sd_control_reset(&g_state);
  ctl_states s;
  sd_real tau[SDT_MAXN];
  for (int t = 0; t < 5; t++) {
    random_states(&seed, &g_model, &s);
    if (t == 3) s.q[0] = (sd_real)NAN;
    step(&s, tau);
  }
  EXPECT_INT(g_state.tick, 5, "five steps");
  EXPECT_INT(g_state.nlimited, 4, "four limited steps");
  EXPECT_INT(g_state.nfault, 1, "one fault");
  EXPECT_GE(sdt_maxabs(g_state.tau_hold, n), 0.1, "a torque is held");
  sd_control_reset(&g_state);
  EXPECT_INT(g_state.tick, 0, "reset: tick 0");
  EXPECT_INT(g_state.nlimited, 0, "reset: limited count cleared");
  EXPECT_INT(g_state.nfault, 0, "reset: fault count cleared");
  EXPECT_INT(g_state.status, 0, "reset: status cleared");
  EXPECT_LE(sdt_maxabs(g_state.tau_hold, SD_MAX_DOF), 0, "reset: nothing held, on every dof");
  // and the next step is an update again
  sd_real ref[SDT_MAXN];
  for (int j = 0; j < n; j++) g_cfg.tau_max[j] = SD_R(0.0);
  random_states(&seed, &g_model, &s);
  memset(&g_ref, 0, sizeof g_ref);
  sd_rnea(&g_model, &g_ref, s.q_d, s.qd_d, s.qdd_d, NULL, ref);
  step(&s, tau);
  EXPECT_LE(sdt_maxdiff(tau, ref, n), 0, "the first step after a reset runs the inverse dynamics");
}

//---------------------------------- free root ---------------------------------------------------

// body 0 floats free (6 dofs, 7 coordinates), two hinges hang below it: ndof 8, nq 9
static int free_root_model(sd_model* m) {
  double eye[9], r1[9], r2[9], ri[9];
  memset(m, 0, sizeof *m);
  sdt_rotation(eye, 0, 0, 1, 0);
  sdt_rotation(r1, 1, 2, 0.5, 0.6);
  sdt_rotation(r2, -0.3, 1, 1, -0.9);
  sdt_rotation(ri, 1, -1, 2, 0.7);
  const double g[3] = {0.3, -0.4, -9.81};
  sdt_put(m->gravity, g, 3);
  m->free_root = 1;
  m->nbody = 3;
  m->ndof = 8;
  const int parent[3] = {-1, 0, 1}, dofnum[3] = {6, 1, 1}, dofadr[3] = {0, 6, 7};
  const double pos[3][3] = {{0, 0, 0}, {0.1, -0.05, -0.2}, {0.0, 0.03, -0.25}};
  const double com[3][3] = {{0.01, 0.02, -0.05}, {-0.02, 0.01, -0.1}, {0.03, 0.0, -0.06}};
  const double mass[3] = {4.0, 1.2, 0.6};
  const double inertia[3][3] = {{0.05, 0.04, 0.03}, {0.01, 0.012, 0.005}, {0.002, 0.0015, 0.001}};
  for (int i = 0; i < 3; i++) {
    m->body_parent[i] = parent[i];
    m->body_dofnum[i] = dofnum[i];
    m->body_dofadr[i] = dofadr[i];
    sdt_put(m->body_pos[i], pos[i], 3);
    sdt_put_rot(m->body_rot[i], i == 0 ? eye : i == 1 ? r1 : r2);
    m->body_mass[i] = (sd_real)mass[i];
    sdt_put(m->body_com[i], com[i], 3);
    sdt_inertia(m->body_inertia[i], inertia[i][0], inertia[i][1], inertia[i][2], ri);
  }
  for (int j = 0; j < m->ndof; j++) sdt_put_rot(m->dof_rot[j], eye);
  int bad = -2;
  int code = sd_model_setup(m, &bad);
  EXPECT_INT(code, SD_OK, "the free-root model is valid");
  EXPECT_INT(m->nq, 9, "origin, quaternion and two hinge angles");
  EXPECT_INT(m->body_qadr[1], 7, "the first hinge's angle follows the root's 7 coordinates");
  EXPECT_INT(m->body_qadr[2], 8, "the second hinge's angle is q[8]");
  return code;
}

// a state of the free-root model with a unit quaternion
static void free_root_states(unsigned* seed, ctl_states* s) {
  random_states(seed, &g_model, s);
  sd_real* qs[2] = {s->q_d, s->q};
  for (int k = 0; k < 2; k++) {
    double x[4], norm = 0;
    for (int i = 0; i < 4; i++) {
      x[i] = sdt_uniform(seed, -1, 1);
      norm += x[i] * x[i];
    }
    for (int i = 0; i < 4; i++) qs[k][3 + i] = (sd_real)(x[i] / sqrt(norm));
  }
}

static void free_root_is_not_actuated(void) {
  if (free_root_model(&g_model) != SD_OK) return;
  int n = g_model.ndof;
  unsigned seed = 48;
  for (int mode = 0; mode < SD_NMODE; mode++) {
    const int U = 2;
    configure(&g_cfg, &g_model, mode, U, 11);
    sdt_context("free root, mode %d", mode);
    EXPECT_INT(sd_control_check(&g_model, &g_cfg), SD_CONTROL_OK,
               "a free root (no ball joint) is accepted");
    memset(&g_data, 0, sizeof g_data);
    memset(&g_ref, 0, sizeof g_ref);
    sd_control_reset(&g_state);
    sd_real held[SDT_MAXN];
    memset(held, 0, sizeof held);
    for (int t = 0; t < 2 * U; t++) {
      ctl_states s;
      sd_real tau[SDT_MAXN], acc[SDT_MAXN];
      free_root_states(&seed, &s);
      // the hinge errors: dof 6 + k at coordinate 7 + k
      double pd[SDT_MAXN];
      memset(pd, 0, sizeof pd);
      for (int k = 0; k < 2; k++) {
        int v = 6 + k, c = 7 + k;
        pd[v] = (double)g_cfg.kp[v] * ((double)s.q_d[c] - (double)s.q[c]) +
                (double)g_cfg.kd[v] * ((double)s.qd_d[v] - (double)s.qd[v]);
      }
      if (t % U == 0) {
        if (mode == SD_MODE_FEEDFORWARD || mode == SD_MODE_FEEDFORWARD_PD) {
          sd_rnea(&g_model, &g_ref, s.q_d, s.qd_d, s.qdd_d, NULL, held);
        } else if (mode == SD_MODE_COMPUTED_TORQUE) {
          // the root's coordinates carry no error: its reference acceleration is qdd_d
          for (int j = 0; j < n; j++) acc[j] = (sd_real)((double)s.qdd_d[j] + pd[j]);
          sd_rnea(&g_model, &g_ref, s.q, s.qd, acc, NULL, held);
        }
        if (mode != SD_MODE_PD) {
          EXPECT_GE(sdt_maxabs(held, 6), 0.1, "the root's wrench is not zero to begin with");
        }
      }
      step(&s, tau);
      sdt_context("free root, mode %d, tick %d", mode, t);
      EXPECT_LE(sdt_maxabs(tau, 6), 0, "the six root torques are always zero: not actuated");
      int with_pd = mode == SD_MODE_FEEDFORWARD_PD || mode == SD_MODE_PD;
      for (int v = 6; v < n; v++) {
        double expect = (mode == SD_MODE_PD ? 0 : (double)held[v]) + (with_pd ? pd[v] : 0);
        EXPECT_NEAR(tau[v], expect, CTL_REL * (fabs((double)held[v]) + fabs(pd[v]) + 1),
                    "hinge torques use the hinge angles at body_qadr, past the quaternion");
      }
    }
  }
  // the last coordinate, past ndof: a bad number there is still seen
  const int U = 2;
  configure(&g_cfg, &g_model, SD_MODE_FEEDFORWARD_PD, U, 12);
  sd_control_reset(&g_state);
  for (int which = 0; which < 2; which++) {
    ctl_states s;
    sd_real tau[SDT_MAXN];
    free_root_states(&seed, &s);
    (which ? s.q : s.q_d)[g_model.nq - 1] = (sd_real)NAN;
    step(&s, tau);
    sdt_context("free root, %s[%d] = NaN", which ? "q" : "q_d", g_model.nq - 1);
    EXPECT_LE(sdt_maxabs(tau, n), 0, "a NaN in the last of the nq coordinates zeroes every torque");
    EXPECT_INT(g_state.status, SD_STATUS_NONFINITE, "and is flagged");
    EXPECT_INT(g_state.nfault, which + 1, "and counted");
  }
}

// finite numbers whose torque overflows: half the largest sd_real (kp e overflows for kp > 2), and
// a speed whose square does (the inverse dynamics' velocity products)
#ifdef SD_SINGLE
#define CTL_HALF_MAX SD_R(1.7e38)
#define CTL_FAST SD_R(1e25)
#else
#define CTL_HALF_MAX SD_R(8.9e307)
#define CTL_FAST SD_R(1e160)
#endif

static void overflow_is_a_fault(void) {
  if (sdt_model_tree6(&g_model) != SD_OK) return;
  int n = g_model.ndof;
  unsigned seed = 47;
  // which: 0 the inverse dynamics of the desired state (feed-forward), 1 that of the measured
  // state (computed torque), 2 the PD, whose inf used to be clamped to the limit
  const int modes[3] = {SD_MODE_FEEDFORWARD, SD_MODE_COMPUTED_TORQUE, SD_MODE_FEEDFORWARD_PD};
  const char* what[3] = {"qd_d huge: RNEA(desired) overflows", "qd huge: RNEA(measured) overflows",
                         "q at half the largest number: kp e overflows"};
  for (int which = 0; which < 3; which++) {
    configure(&g_cfg, &g_model, modes[which], 2, 48);
    for (int j = 0; j < n; j++) g_cfg.tau_max[j] = SD_R(3.0);
    memset(&g_data, 0, sizeof g_data);
    sd_control_reset(&g_state);
    ctl_states s;
    sd_real tau[SDT_MAXN];
    random_states(&seed, &g_model, &s);
    step(&s, tau);   // ticks 0 and 1: good steps
    step(&s, tau);
    EXPECT_INT(g_state.status & ~SD_STATUS_LIMITED, 0, "good steps first");
    int warned = g_data.warning[SD_WARN_NONFINITE];
    long limited = g_state.nlimited;
    if (which == 0) s.qd_d[n - 1] = CTL_FAST;
    if (which == 1) s.qd[n - 1] = CTL_FAST;
    if (which == 2) s.q[n - 1] = -CTL_HALF_MAX;
    step(&s, tau);   // tick 2: an update
    sdt_context("%s", what[which]);
    EXPECT_INT(g_state.status, SD_STATUS_OVERFLOW, "flagged SD_STATUS_OVERFLOW");
    EXPECT_LE(sdt_maxabs(tau, n), 0, "every torque zero: not the core's zeroed overflow, not a clamp");
    EXPECT_INT(g_state.nfault, 1, "counted as a fault");
    EXPECT_INT(g_state.nlimited, limited, "not as limiting");
    EXPECT_INT(g_data.warning[SD_WARN_NONFINITE] > warned, which < 2,
               "the inverse dynamics counted their warning (the PD's overflow has none)");
    random_states(&seed, &g_model, &s);
    step(&s, tau);   // tick 3: between updates, but after a fault the inverse dynamics are redone
    EXPECT_INT(g_state.status & ~SD_STATUS_LIMITED, 0, "the next good step is not a fault");
    EXPECT_GE(sdt_maxabs(tau, n), 1e-3, "and commands a torque again");
  }
}

//---------------------------------- closed loop -------------------------------------------------

// a pendulum on one hinge about the base z axis, gravity along -y, com at 0.35 m along -y
static int pendulum(sd_model* m) {
  memset(m, 0, sizeof *m);
  const double g[3] = {0, -9.81, 0}, pos[3] = {0.1, 0.2, 0.3}, com[3] = {0, -0.35, 0};
  const double inertia[6] = {0.004, 0.003, 0.0035, 0, 0.0003, 0.0002};
  const double eye[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  m->nbody = 1;
  m->ndof = 1;
  m->body_parent[0] = -1;
  m->body_dofnum[0] = 1;
  sdt_put(m->gravity, g, 3);
  sdt_put(m->body_pos[0], pos, 3);
  sdt_put_rot(m->body_rot[0], eye);
  sdt_put_rot(m->dof_rot[0], eye);
  m->body_mass[0] = SD_R(1.3);
  sdt_put(m->body_com[0], com, 3);
  sdt_put(m->body_inertia[0], inertia, 6);
  int bad;
  int code = sd_model_setup(m, &bad);
  EXPECT_INT(code, SD_OK, "the pendulum is a valid model");
  return code;
}

// run the loop for 2 s at 1 kHz from q0; the largest |q - target| over the run and at the end
static void run_loop(sd_real target, sd_real q0, double* worst, double* last) {
  const sd_real dt = SD_R(0.001);
  sd_real q_d = target, zero = SD_R(0.0), q = q0, qd = SD_R(0.0), tau;
  memset(&g_data, 0, sizeof g_data);
  sd_control_reset(&g_state);
  *worst = 0;
  for (int t = 0; t < 2000; t++) {
    sd_control_step(&g_model, &g_data, &g_cfg, &g_state, &q_d, &zero, &zero, &q, &qd, &tau);
    sd_step(&g_model, &g_data, &q, &qd, &tau, NULL, dt, SD_RK4);
    double e = fabs((double)q - (double)target);
    if (e > *worst || e != e) *worst = e;
  }
  *last = fabs((double)q - (double)target);
}

static void closed_loop_holds_pendulum(void) {
  if (pendulum(&g_model) != SD_OK) return;
  memset(&g_cfg, 0, sizeof g_cfg);
  g_cfg.mode = SD_MODE_FEEDFORWARD_PD;
  g_cfg.update_ticks = 10;
  g_cfg.kp[0] = SD_R(20.0);
  g_cfg.kd[0] = SD_R(2.0);
  EXPECT_INT(sd_control_check(&g_model, &g_cfg), SD_CONTROL_OK, "a valid configuration");
  const sd_real target = SD_R(0.7);
  double worst, last;
  run_loop(target, target, &worst, &last);
  sdt_context("held at 0.7 rad from rest on target, 2 s at 1 kHz, update_ticks 10");
  EXPECT_LE(worst, CTL_HOLD_TOL,
            "feed-forward gravity plus PD holds the pendulum at its target angle");
  EXPECT_INT(g_state.tick, 2000, "2000 small steps");
  EXPECT_INT(g_state.nfault + g_state.nlimited, 0, "no fault, no limit");
  // from 0.05 rad off, the PD pulls it back: a damped oscillation of about 12 rad/s, zeta 0.5
  run_loop(target, SD_R(0.75), &worst, &last);
  sdt_context("released 0.05 rad off the target");
  EXPECT_LE(worst, 0.05 + CTL_HOLD_TOL, "the error never grows beyond the initial offset");
  EXPECT_LE(last, 1e-5, "after 2 s the error has decayed by more than three decades");
  // without the feed-forward (PD mode) gravity pulls it to a steady error m g l sin(q) / kp
  g_cfg.mode = SD_MODE_PD;
  run_loop(target, target, &worst, &last);
  sdt_context("PD mode, no feed-forward");
  EXPECT_GE(last, 0.05, "PD alone leaves a gravity sag: the feed-forward does the holding");
}

// friction compensation: F_c tanh(qd_d / speed) + F_v qd_d on top of the held RNEA, every small
// step, in the feed-forward modes; none in PD mode; a bad friction refused at the check
static void friction_is_compensated_on_the_desired_velocity(void) {
  unsigned seed = 77;
  for (int model = 0; model < SDT_NMODEL; model++) {
    const char* name;
    if (sdt_model_by_index(&g_model, model, &name) != SD_OK || g_model.free_root) continue;
    int n = g_model.ndof;
    configure(&g_cfg, &g_model, SD_MODE_FEEDFORWARD, 1, 9);
    g_cfg.friction_speed = SD_R(0.1);
    for (int j = 0; j < n; j++) {
      g_cfg.friction_coulomb[j] = (sd_real)sdt_uniform(&seed, 0.05, 0.5);
      g_cfg.friction_viscous[j] = (sd_real)sdt_uniform(&seed, 0.0, 0.2);
    }
    EXPECT_INT(sd_control_check(&g_model, &g_cfg), SD_CONTROL_OK, "frictions >= 0 with a speed are accepted");
    sd_control_reset(&g_state);
    ctl_states s;
    sd_real tau[SDT_MAXN], ref[SDT_MAXN];
    random_states(&seed, &g_model, &s);
    s.qd_d[0] = SD_R(0.0);          // at rest: no Coulomb term at all
    sd_rnea(&g_model, &g_ref, s.q_d, s.qd_d, s.qdd_d, NULL, ref);
    step(&s, tau);
    double worst = 0;
    for (int j = 0; j < n; j++) {
      double qd = (double)s.qd_d[j];
      double expected = (double)ref[j] + (double)g_cfg.friction_coulomb[j] * tanh(qd / 0.1) +
                        (double)g_cfg.friction_viscous[j] * qd;
      worst = fmax(worst, fabs((double)tau[j] - expected) / fmax(1.0, fabs(expected)));
    }
    sdt_context("model %s", name);
    EXPECT_LE(worst, CTL_REL * 10, "tau = RNEA + F_c tanh(qd_d / 0.1) + F_v qd_d");
    g_cfg.mode = SD_MODE_PD;
    sd_control_reset(&g_state);
    step(&s, tau);
    double pd[SDT_MAXN], off = 0;
    pd_torque(&g_model, &g_cfg, &s, pd);
    for (int j = 0; j < n; j++) off = fmax(off, fabs((double)tau[j] - pd[j]));
    EXPECT_LE(off, CTL_REL * 100, "PD mode compensates nothing: no feed-forward at all");
  }
  if (sdt_model_chain3(&g_model) != SD_OK) return;
  CHECK_REJECTS(g_cfg.friction_coulomb[1] = SD_R(-0.1), SD_CONTROL_ERR_FRICTION,
                "a negative Coulomb friction would push the joint along");
  CHECK_REJECTS(g_cfg.friction_viscous[0] = (sd_real)NAN, SD_CONTROL_ERR_FRICTION, "a NaN viscous friction");
  CHECK_REJECTS(g_cfg.friction_coulomb[0] = SD_R(0.2), SD_CONTROL_ERR_FRICTION,
                "Coulomb friction needs a smoothing speed (0 would divide by zero)");
  CHECK_REJECTS((g_cfg.friction_coulomb[0] = SD_R(0.2), g_cfg.friction_speed = (sd_real)INFINITY),
                SD_CONTROL_ERR_FRICTION, "an infinite smoothing speed is refused");
}

const sdt_test sdt_control_tests[] = {
  {"friction_is_compensated_on_the_desired_velocity", friction_is_compensated_on_the_desired_velocity},
  {"check_accepts_good_configs", check_accepts_good_configs},
  {"check_rejects_bad_configs", check_rejects_bad_configs},
  {"check_codes_have_messages", check_codes_have_messages},
  {"check_rejects_ball_joints", check_rejects_ball_joints},
  {"feedforward_is_rnea_held", feedforward_is_rnea_held},
  {"feedforward_pd_adds_joint_pd", feedforward_pd_adds_joint_pd},
  {"computed_torque_is_rnea_at_measured_state", computed_torque_is_rnea_at_measured_state},
  {"pd_mode_has_no_inverse_dynamics", pd_mode_has_no_inverse_dynamics},
  {"pd_acts_on_lowpassed_errors", pd_acts_on_lowpassed_errors},
  {"limits_clamp_and_count", limits_clamp_and_count},
  {"nonfinite_input_is_a_fault", nonfinite_input_is_a_fault},
  {"overflow_is_a_fault", overflow_is_a_fault},
  {"reset_clears_everything", reset_clears_everything},
  {"free_root_is_not_actuated", free_root_is_not_actuated},
  {"closed_loop_holds_pendulum", closed_loop_holds_pendulum},
  {0, 0},
};
