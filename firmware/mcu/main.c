// main.c: the Cortex-M4F link check of the servodyn core.
//
// Builds a 7-body arm-like chain (clavicle 2 dofs, shoulder 3, elbow 1, pronation 1, wrist 2,
// finger 1, a welded tool: 10 dofs) from solid primitives, then runs every entry point of the
// core once: sd_model_setup, sd_rnea, sd_forward and sd_step (RK4 and Euler), then the CAN motor
// frame codec in float (canmotor_check.c). The exit code tells the host what happened:
//   0 ok, 1 model rejected, 2 a non-finite result, 3 forward(rnea(qdd)) != qdd,
//   4 a warning was counted, 5 the CAN codec's check failed, 99 a CPU fault (startup.c)
#include "board.h"
#include "servodyn.h"

int canmotor_check(void);   // canmotor_check.c: 0, or the number of the check that failed

enum { BODY_CLAVICLE, BODY_UPPER_ARM, BODY_FOREARM, BODY_RADIUS, BODY_HAND, BODY_FINGER,
       BODY_TOOL, NBODY };

static sd_model g_model;
static sd_data g_data;

static void rot_x(sd_real R[9], sd_real angle) {
  sd_real c = sd_cos(angle), s = sd_sin(angle);
  const sd_real r[9] = {1, 0, 0, 0, c, -s, 0, s, c};
  for (int k = 0; k < 9; k++) R[k] = r[k];
}

static void rot_y(sd_real R[9], sd_real angle) {
  sd_real c = sd_cos(angle), s = sd_sin(angle);
  const sd_real r[9] = {c, 0, s, 0, 1, 0, -s, 0, c};
  for (int k = 0; k < 9; k++) R[k] = r[k];
}

static void rot_identity(sd_real R[9]) {
  for (int k = 0; k < 9; k++) R[k] = (k % 4 == 0) ? SD_R(1.0) : SD_R(0.0);
}

// the primitives have their axis along z; a link along x swaps the xx and zz moments
static void axis_along_x(sd_real inertia[6]) {
  sd_real zz = inertia[2];
  inertia[2] = inertia[0];
  inertia[0] = zz;
}

// one joint: parent, dofs, joint origin in the parent; the fixed rotation is set by the caller
static void joint(int body, int parent, int dofnum, sd_real x, sd_real y, sd_real z) {
  g_model.body_parent[body] = parent;
  g_model.body_dofnum[body] = dofnum;
  g_model.body_dofadr[body] = g_model.ndof;
  g_model.body_pos[body][0] = x;
  g_model.body_pos[body][1] = y;
  g_model.body_pos[body][2] = z;
  rot_identity(g_model.body_rot[body]);
  for (int k = 0; k < dofnum; k++) rot_identity(g_model.dof_rot[g_model.ndof + k]);
  g_model.ndof += dofnum;
}

static void mass(int body, sd_real m, sd_real cx, sd_real cy, sd_real cz) {
  g_model.body_mass[body] = m;
  g_model.body_com[body][0] = cx;
  g_model.body_com[body][1] = cy;
  g_model.body_com[body][2] = cz;
}

// a right arm hanging from a fixed torso, mass fractions of a 70 kg body (paper Fig. 2)
static int build_arm(void) {
  sd_model* m = &g_model;
  sd_real com_z;
  int bad = 0;
  m->nbody = NBODY;
  m->ndof = 0;
  m->gravity[0] = 0;
  m->gravity[1] = 0;
  m->gravity[2] = SD_R(-9.81);

  // clavicle: a cylinder along x, two dofs (elevation, protraction)
  joint(BODY_CLAVICLE, -1, 2, 0, SD_R(0.02), 0);
  rot_x(m->dof_rot[1], SD_R(1.5707963));
  mass(BODY_CLAVICLE, SD_R(0.5), SD_R(0.075), 0, 0);
  bad |= sd_inertia_cylinder(SD_R(0.5), SD_R(0.02), SD_R(0.15), m->body_inertia[BODY_CLAVICLE]);
  axis_along_x(m->body_inertia[BODY_CLAVICLE]);

  // upper arm: a frustum along z, a 3-dof shoulder whose last dof turns the arm about itself
  joint(BODY_UPPER_ARM, BODY_CLAVICLE, 3, SD_R(0.15), 0, 0);
  rot_y(m->body_rot[BODY_UPPER_ARM], SD_R(1.5707963));
  rot_x(m->dof_rot[3], SD_R(-1.5707963));
  rot_y(m->dof_rot[4], SD_R(1.5707963));
  bad |= sd_inertia_frustum(SD_R(1.96), SD_R(0.05), SD_R(0.035), SD_R(0.30), &com_z,
                            m->body_inertia[BODY_UPPER_ARM]);
  mass(BODY_UPPER_ARM, SD_R(1.96), 0, 0, com_z);

  // forearm, elbow side: a frustum along x, the elbow hinge across the upper arm
  joint(BODY_FOREARM, BODY_UPPER_ARM, 1, 0, 0, SD_R(0.30));
  rot_x(m->body_rot[BODY_FOREARM], SD_R(1.5707963));
  bad |= sd_inertia_frustum(SD_R(0.6), SD_R(0.04), SD_R(0.035), SD_R(0.12), &com_z,
                            m->body_inertia[BODY_FOREARM]);
  axis_along_x(m->body_inertia[BODY_FOREARM]);
  mass(BODY_FOREARM, SD_R(0.6), com_z, 0, 0);

  // forearm, wrist side: a frustum along its own axis z, pronation about that axis
  joint(BODY_RADIUS, BODY_FOREARM, 1, SD_R(0.12), 0, 0);
  rot_y(m->body_rot[BODY_RADIUS], SD_R(1.5707963));
  bad |= sd_inertia_frustum(SD_R(0.52), SD_R(0.035), SD_R(0.028), SD_R(0.13), &com_z,
                            m->body_inertia[BODY_RADIUS]);
  mass(BODY_RADIUS, SD_R(0.52), 0, 0, com_z);

  // hand: an ellipsoid along x, a 2-dof wrist (flexion, deviation)
  joint(BODY_HAND, BODY_RADIUS, 2, 0, 0, SD_R(0.13));
  rot_x(m->body_rot[BODY_HAND], SD_R(1.5707963));
  rot_x(m->dof_rot[g_model.body_dofadr[BODY_HAND] + 1], SD_R(1.5707963));
  bad |= sd_inertia_ellipsoid(SD_R(0.42), SD_R(0.045), SD_R(0.04), SD_R(0.012),
                              m->body_inertia[BODY_HAND]);
  mass(BODY_HAND, SD_R(0.42), SD_R(0.05), 0, 0);

  // finger: a thin cylinder along x on one hinge
  joint(BODY_FINGER, BODY_HAND, 1, SD_R(0.09), 0, SD_R(0.01));
  bad |= sd_inertia_cylinder(SD_R(0.05), SD_R(0.008), SD_R(0.06), m->body_inertia[BODY_FINGER]);
  axis_along_x(m->body_inertia[BODY_FINGER]);
  mass(BODY_FINGER, SD_R(0.05), SD_R(0.03), 0, 0);

  // tool: a ball welded to the fingertip (a 0-dof joint)
  joint(BODY_TOOL, BODY_FINGER, 0, SD_R(0.06), 0, 0);
  rot_x(m->body_rot[BODY_TOOL], SD_R(0.5));
  bad |= sd_inertia_sphere(SD_R(0.1), SD_R(0.02), m->body_inertia[BODY_TOOL]);
  mass(BODY_TOOL, SD_R(0.1), SD_R(0.02), 0, 0);

  if (bad) return SD_ERR_INERTIA;
  int bad_body;
  return sd_model_setup(m, &bad_body);
}

static int all_finite(const sd_real* x, int n) {
  for (int i = 0; i < n; i++) {
    if (!SD_ISFINITE(x[i])) return 0;
  }
  return 1;
}

int main(void) {
  board_stack_paint();
  int code = build_arm();
  if (code != SD_OK) {
    board_write("servodyn-mcu: model rejected: ");
    board_write(sd_strerror(code));
    board_write("\n");
    return 1;
  }
  int n = g_model.ndof;
  if (n != 10) return 1;

  // a state in the middle of the workspace, a wrench on the tool
  static const sd_real q0[10] = {SD_R(0.1), SD_R(-0.2), SD_R(0.4), SD_R(0.3), SD_R(-0.5),
                                 SD_R(1.1), SD_R(0.6), SD_R(0.2), SD_R(-0.3), SD_R(0.4)};
  static const sd_real qd0[10] = {SD_R(0.5), SD_R(-0.3), SD_R(1.0), SD_R(-0.7), SD_R(0.2),
                                  SD_R(1.5), SD_R(-1.0), SD_R(0.8), SD_R(0.3), SD_R(-0.6)};
  static const sd_real qdd0[10] = {SD_R(1.0), SD_R(-2.0), SD_R(0.5), SD_R(3.0), SD_R(-1.5),
                                   SD_R(2.0), SD_R(-0.5), SD_R(1.2), SD_R(-2.5), SD_R(0.7)};
  sd_real q[10], qd[10], tau[10], qdd[10], f_ext[6 * NBODY];
  for (int i = 0; i < 6 * NBODY; i++) f_ext[i] = 0;
  f_ext[6 * BODY_TOOL + 5] = SD_R(-2.0);   // 2 N pressing down on the tool, along its z

  // inverse then direct dynamics: the accelerations must come back
  sd_rnea(&g_model, &g_data, q0, qd0, qdd0, f_ext, tau);
  sd_forward(&g_model, &g_data, q0, qd0, tau, f_ext, qdd);
  if (!all_finite(tau, n) || !all_finite(qdd, n)) return 2;
  sd_real worst = 0;
  for (int i = 0; i < n; i++) {
    sd_real err = sd_fabs(qdd[i] - qdd0[i]);
    if (err > worst) worst = err;
  }
  if (worst > SD_R(1e-3)) return 3;

  // 100 ms of RK4 and 10 ms of Euler at 1 ms, holding the arm against gravity
  for (int i = 0; i < n; i++) {
    q[i] = q0[i];
    qd[i] = qd0[i];
  }
  sd_real zero[10] = {0};
  sd_rnea(&g_model, &g_data, q0, zero, zero, NULL, tau);
  for (int step = 0; step < 100; step++) {
    sd_step(&g_model, &g_data, q, qd, tau, f_ext, SD_R(0.001), SD_RK4);
  }
  for (int step = 0; step < 10; step++) {
    sd_step(&g_model, &g_data, q, qd, tau, NULL, SD_R(0.001), SD_EULER);
  }
  if (!all_finite(q, n) || !all_finite(qd, n)) return 2;
  if (g_data.warning[SD_WARN_NONFINITE] || g_data.warning[SD_WARN_SINGULAR]) return 4;
  int can = canmotor_check();
  if (can) {
    board_write("servodyn-mcu: CAN codec check ");
    board_write_int(can);
    board_write(" failed\n");
    return 5;
  }

  board_write("servodyn-mcu: ok, ");
  board_write_int(n);
  board_write(" dofs, max |forward(rnea(qdd)) - qdd| = ");
  board_write_int((long)(worst * SD_R(1e6)));
  board_write("e-6 rad/s^2, CAN codec in float ok, stack used ");
  board_write_int((long)board_stack_used());
  board_write(" bytes\n");
  return 0;
}
