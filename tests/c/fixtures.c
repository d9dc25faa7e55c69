// fixtures.c: test models, states and reference mechanics (see fixtures.h).
#include "fixtures.h"

#include <math.h>
#include <string.h>

#include "harness.h"

double sdt_uniform(unsigned* state, double lo, double hi) {
  // 32-bit LCG (Numerical Recipes constants); the top 24 bits are plenty for test data
  *state = *state * 1664525u + 1013904223u;
  return lo + (hi - lo) * (double)(*state >> 8) / 16777216.0;
}

void sdt_rotation(double R[9], double x, double y, double z, double angle) {
  double n = sqrt(x*x + y*y + z*z);
  x /= n; y /= n; z /= n;
  double c = cos(angle), s = sin(angle), t = 1 - c;
  R[0] = t*x*x + c;   R[1] = t*x*y - s*z; R[2] = t*x*z + s*y;
  R[3] = t*x*y + s*z; R[4] = t*y*y + c;   R[5] = t*y*z - s*x;
  R[6] = t*x*z - s*y; R[7] = t*y*z + s*x; R[8] = t*z*z + c;
}

void sdt_put(sd_real* dst, const double* src, int n) {
  for (int i = 0; i < n; i++) dst[i] = (sd_real)src[i];
}

void sdt_put_rot(sd_real dst[9], const double R[9]) {
  sdt_put(dst, R, 9);
}

void sdt_inertia(sd_real dst[6], double a, double b, double c, const double R[9]) {
  // I = R diag(a, b, c) R'
  const double d[3] = {a, b, c};
  double I[9];
  for (int i = 0; i < 3; i++) {
    for (int j = 0; j < 3; j++) {
      I[3*i+j] = R[3*i]*d[0]*R[3*j] + R[3*i+1]*d[1]*R[3*j+1] + R[3*i+2]*d[2]*R[3*j+2];
    }
  }
  const double packed[6] = {I[0], I[4], I[8], I[1], I[2], I[5]};
  sdt_put(dst, packed, 6);
}

#define SDT_HALF_PI 1.5707963267948966

static void mulmm(double r[9], const double A[9], const double B[9]);

static void identity(double R[9]) {
  memset(R, 0, 9 * sizeof(double));
  R[0] = R[4] = R[8] = 1;
}

// one body of a test model
static void put_body(sd_model* m, int i, int parent, int dofnum, double px, double py,
                     double pz, const double rot[9], double mass, double cx, double cy,
                     double cz, double ia, double ib, double ic, const double inertia_rot[9]) {
  m->body_parent[i] = parent;
  m->body_dofnum[i] = dofnum;
  m->body_dofadr[i] = m->ndof;
  m->ndof += dofnum;
  const double pos[3] = {px, py, pz}, com[3] = {cx, cy, cz};
  sdt_put(m->body_pos[i], pos, 3);
  sdt_put_rot(m->body_rot[i], rot);
  m->body_mass[i] = (sd_real)mass;
  sdt_put(m->body_com[i], com, 3);
  sdt_inertia(m->body_inertia[i], ia, ib, ic, inertia_rot);
  double eye[9];
  identity(eye);
  for (int k = 0; k < dofnum; k++) sdt_put_rot(m->dof_rot[m->body_dofadr[i] + k], eye);
}

static void clear(sd_model* m) {
  memset(m, 0, sizeof *m);
  const double g[3] = {0.3, -0.4, -9.81};   // not along an axis, so every term is exercised
  sdt_put(m->gravity, g, 3);
}

void sdt_fill_chain3(sd_model* m) {
  double r0[9], r1[9], r2[9], ri[9];
  clear(m);
  sdt_rotation(r0, 1, 2, 3, 0.4);
  sdt_rotation(r1, 0, 1, 1, -0.3);
  sdt_rotation(r2, 1, 1, 0, 0.7);
  sdt_rotation(ri, -1, 0.5, 2, 0.9);
  //        body parent dofs position              rotation mass com                    inertia
  put_body(m, 0, -1, 3, 0.05, 0.10, 0.20, r0, 2.0, 0.02, -0.01, -0.15, 0.020, 0.018, 0.006, ri);
  put_body(m, 1, 0, 2, 0.01, -0.02, -0.30, r1, 1.2, -0.01, 0.03, -0.12, 0.009, 0.011, 0.004, r2);
  put_body(m, 2, 1, 1, 0.00, 0.03, -0.25, r2, 0.6, 0.04, 0.00, -0.05, 0.002, 0.0015, 0.001, r0);
  m->nbody = 3;
  // later dofs of a joint sit in turned frames, like a gimbal: the ball joint's axes z0, z1, z2
  // are independent unless q1 = +-pi/2 (gimbal lock), its third frame also turned about z2
  double rx[9], ry[9], rz[9], rg[9];
  sdt_rotation(rx, 1, 0, 0, -SDT_HALF_PI);
  sdt_rotation(ry, 0, 1, 0, SDT_HALF_PI);
  sdt_rotation(rz, 0, 0, 1, 0.4);
  mulmm(rg, ry, rz);
  sdt_put_rot(m->dof_rot[1], rx);
  sdt_put_rot(m->dof_rot[2], rg);
  sdt_rotation(rg, 1, 0, 0.2, 1.4);
  sdt_put_rot(m->dof_rot[4], rg);
}

static int setup_checked(sd_model* m, const char* name) {
  int bad = -2;
  int code = sd_model_setup(m, &bad);
  sdt_context("test model %s, bad_body %d (%s)", name, bad, sd_strerror(code));
  EXPECT_INT(code, SD_OK, "the test models are valid and must be accepted");
  sdt_context("%s", "");
  return code;
}

int sdt_model_chain3(sd_model* m) {
  sdt_fill_chain3(m);
  return setup_checked(m, "chain3");
}

int sdt_model_tree6(sd_model* m) {
  double r0[9], r1[9], r2[9], r3[9], eye[9];
  clear(m);
  identity(eye);
  sdt_rotation(r0, 0.2, -1, 0.4, 0.8);
  sdt_rotation(r1, 1, 0, 0, 1.2);
  sdt_rotation(r2, 0, 0, 1, -0.6);
  sdt_rotation(r3, 1, -1, 1, 2.0);
  //        body parent dofs position              rotation mass com                    inertia
  put_body(m, 0, -1, 3, 0.00, 0.00, 0.00, eye, 3.0, 0.00, 0.01, -0.20, 0.040, 0.035, 0.010, r1);
  put_body(m, 1, 0, 2, 0.10, 0.00, -0.35, r0, 1.5, 0.02, -0.02, -0.10, 0.010, 0.012, 0.005, r2);
  put_body(m, 2, 1, 1, 0.00, -0.05, -0.22, r1, 0.4, 0.00, 0.02, -0.06, 0.001, 0.0012, 0.0008, r3);
  put_body(m, 3, 0, 0, -0.10, 0.02, -0.30, r3, 0.8, 0.03, 0.00, 0.00, 0.003, 0.002, 0.002, r0);
  put_body(m, 4, 3, 1, 0.00, 0.00, 0.12, r2, 0.5, 0.00, 0.00, 0.08, 0.0015, 0.0015, 0.0005, eye);
  put_body(m, 5, -1, 1, 0.30, 0.10, 0.00, r0, 1.0, 0.10, 0.00, 0.01, 0.001, 0.004, 0.004, r1);
  m->nbody = 6;
  // the ball joint locks at q1 = +-pi/2, as in chain3
  double ry[9], rx[9], rz[9], rg[9];
  sdt_rotation(ry, 0, 1, 0, SDT_HALF_PI);
  sdt_rotation(rx, 1, 0, 0, SDT_HALF_PI);
  sdt_rotation(rz, 0, 0, 1, -0.5);
  mulmm(rg, rx, rz);
  sdt_put_rot(m->dof_rot[1], ry);
  sdt_put_rot(m->dof_rot[2], rg);
  sdt_put_rot(m->dof_rot[4], r1);
  return setup_checked(m, "tree6");
}

int sdt_model_by_index(sd_model* m, int index, const char** name) {
  if (index == 0) {
    *name = "chain3";
    return sdt_model_chain3(m);
  }
  *name = "tree6";
  return sdt_model_tree6(m);
}

void sdt_random_vector(unsigned* seed, double lo, double hi, int n, sd_real* r, double* d) {
  for (int i = 0; i < n; i++) {
    r[i] = (sd_real)sdt_uniform(seed, lo, hi);
    if (d) d[i] = (double)r[i];
  }
}

//---------------------------------- reference mechanics -----------------------------------------

static void get(double* dst, const sd_real* src, int n) {
  for (int i = 0; i < n; i++) dst[i] = (double)src[i];
}

static void mulmm(double r[9], const double A[9], const double B[9]) {
  double t[9];
  for (int i = 0; i < 3; i++) {
    for (int j = 0; j < 3; j++) {
      t[3*i+j] = A[3*i]*B[j] + A[3*i+1]*B[3+j] + A[3*i+2]*B[6+j];
    }
  }
  memcpy(r, t, sizeof t);
}

static void mulmv(double r[3], const double A[9], const double v[3]) {
  double t[3];
  for (int i = 0; i < 3; i++) t[i] = A[3*i]*v[0] + A[3*i+1]*v[1] + A[3*i+2]*v[2];
  memcpy(r, t, sizeof t);
}

static void mulmtv(double r[3], const double A[9], const double v[3]) {
  double t[3];
  for (int i = 0; i < 3; i++) t[i] = A[i]*v[0] + A[3+i]*v[1] + A[6+i]*v[2];
  memcpy(r, t, sizeof t);
}

static void cross(double r[3], const double a[3], const double b[3]) {
  double t[3] = {a[1]*b[2] - a[2]*b[1], a[2]*b[0] - a[0]*b[2], a[0]*b[1] - a[1]*b[0]};
  memcpy(r, t, sizeof t);
}

static double dot(const double a[3], const double b[3]) {
  return a[0]*b[0] + a[1]*b[1] + a[2]*b[2];
}

void sdt_kinematics(const sd_model* m, const double* q, const double* qd, sdt_kin* k) {
  for (int i = 0; i < m->nbody; i++) {
    int parent = m->body_parent[i];
    double Rp[9], pp[3] = {0, 0, 0}, wp[3] = {0, 0, 0}, vp[3] = {0, 0, 0};
    identity(Rp);
    if (parent >= 0) {
      memcpy(Rp, k->R[parent], sizeof Rp);
      memcpy(pp, k->p[parent], sizeof pp);
      memcpy(wp, k->w[parent], sizeof wp);
      memcpy(vp, k->v[parent], sizeof vp);
    }
    // the joint origin: fixed in the parent, so it moves with the parent's motion
    double pos[3], r[3], wxr[3];
    get(pos, m->body_pos[i], 3);
    mulmv(r, Rp, pos);
    cross(wxr, wp, r);
    for (int j = 0; j < 3; j++) {
      k->p[i][j] = pp[j] + r[j];
      k->v[i][j] = vp[j] + wxr[j];
    }
    // the dof frames: R_first = Rp body_rot; dof d turns its frame R_d = R_(d-1) dof_rot Rz(q)
    double R[9], fixed[9];
    get(fixed, m->body_rot[i], 9);
    mulmm(R, Rp, fixed);
    memcpy(k->w[i], wp, sizeof wp);
    for (int d = m->body_dofadr[i]; d < m->body_dofadr[i] + m->body_dofnum[i]; d++) {
      get(fixed, m->dof_rot[d], 9);
      mulmm(R, R, fixed);
      for (int j = 0; j < 3; j++) k->w[i][j] += qd[d] * R[3*j+2];   // qd times the z axis
      double c = cos(q[d]), s = sin(q[d]);
      const double Rz[9] = {c, -s, 0, s, c, 0, 0, 0, 1};
      mulmm(R, R, Rz);
    }
    memcpy(k->R[i], R, sizeof R);
  }
}

double sdt_kinetic_energy(const sd_model* m, const sdt_kin* k) {
  double energy = 0;
  for (int i = 0; i < m->nbody; i++) {
    double com[3], c[3], wxc[3], vc[3], wb[3], Iw[3], in[6];
    get(com, m->body_com[i], 3);
    get(in, m->body_inertia[i], 6);
    mulmv(c, k->R[i], com);
    cross(wxc, k->w[i], c);
    for (int j = 0; j < 3; j++) vc[j] = k->v[i][j] + wxc[j];
    // rotational part in the body frame: w_b' I_c w_b
    mulmtv(wb, k->R[i], k->w[i]);
    Iw[0] = in[0]*wb[0] + in[3]*wb[1] + in[4]*wb[2];
    Iw[1] = in[3]*wb[0] + in[1]*wb[1] + in[5]*wb[2];
    Iw[2] = in[4]*wb[0] + in[5]*wb[1] + in[2]*wb[2];
    energy += 0.5 * (double)m->body_mass[i] * dot(vc, vc) + 0.5 * dot(wb, Iw);
  }
  return energy;
}

double sdt_potential_energy(const sd_model* m, const sdt_kin* k) {
  double g[3], energy = 0;
  get(g, m->gravity, 3);
  for (int i = 0; i < m->nbody; i++) {
    double com[3], c[3];
    get(com, m->body_com[i], 3);
    mulmv(c, k->R[i], com);
    for (int j = 0; j < 3; j++) c[j] += k->p[i][j];
    energy -= (double)m->body_mass[i] * dot(g, c);
  }
  return energy;
}

double sdt_wrench_power(const sd_model* m, const sdt_kin* k, const sd_real* f_ext) {
  double power = 0;
  for (int i = 0; i < m->nbody; i++) {
    double wb[3], vb[3], n[3], f[3];
    mulmtv(wb, k->R[i], k->w[i]);
    mulmtv(vb, k->R[i], k->v[i]);
    get(n, f_ext + 6*i, 3);
    get(f, f_ext + 6*i + 3, 3);
    power += dot(n, wb) + dot(f, vb);
  }
  return power;
}

double sdt_maxdiff(const sd_real* a, const sd_real* b, int n) {
  double worst = 0;
  for (int i = 0; i < n; i++) {
    double e = fabs((double)a[i] - (double)b[i]);
    if (e > worst || e != e) worst = e;   // once NaN, stays NaN
  }
  return worst;
}

double sdt_maxabs(const sd_real* a, int n) {
  double worst = 0;
  for (int i = 0; i < n; i++) {
    double e = fabs((double)a[i]);
    if (e > worst || e != e) worst = e;
  }
  return worst;
}

double sdt_dot(const sd_real* a, const sd_real* b, int n) {
  double s = 0;
  for (int i = 0; i < n; i++) s += (double)a[i] * (double)b[i];
  return s;
}
