// model.c: validation of a model, its derived constants, and inertias of solid primitives.
#include "servodyn.h"
#include "sd_math.h"

// tolerance of the orthonormality test: loose enough for a double rotation rounded to float
#define SD_ROT_TOL (SD_R(1e4) * SD_EPS)

static int rotation_ok(const sd_real R[9]) {
  if (!sd_allfinite(R, 9)) {
    return 0;
  }
  // R R' = 1 and det R = +1
  for (int i = 0; i < 3; i++) {
    for (int j = 0; j < 3; j++) {
      sd_real dot = R[3*i]*R[3*j] + R[3*i+1]*R[3*j+1] + R[3*i+2]*R[3*j+2];
      sd_real want = (i == j) ? SD_R(1) : SD_R(0);
      if (sd_fabs(dot - want) > SD_ROT_TOL) {
        return 0;
      }
    }
  }
  sd_real det = R[0]*(R[4]*R[8] - R[5]*R[7]) - R[1]*(R[3]*R[8] - R[5]*R[6])
              + R[2]*(R[3]*R[7] - R[4]*R[6]);
  return det > 0;
}

static int is_identity(const sd_real R[9]) {
  for (int i = 0; i < 9; i++) {
    sd_real want = (i % 4 == 0) ? SD_R(1) : SD_R(0);
    if (sd_fabs(R[i] - want) > SD_ROT_TOL) {
      return 0;
    }
  }
  return 1;
}

// the principal minors of a symmetric 3x3 (xx yy zz xy xz yz) are all >= -tol (> tol if strict)
static int symmetric_definite(const sd_real S[6], sd_real tol, int strict) {
  sd_real m1[3] = {S[0], S[1], S[2]};
  sd_real m2[3] = {S[0]*S[1] - S[3]*S[3], S[0]*S[2] - S[4]*S[4], S[1]*S[2] - S[5]*S[5]};
  sd_real det = S[0]*(S[1]*S[2] - S[5]*S[5]) - S[3]*(S[3]*S[2] - S[5]*S[4])
              + S[4]*(S[3]*S[5] - S[1]*S[4]);
  sd_real t2 = tol * tol, t3 = t2 * tol;
  for (int i = 0; i < 3; i++) {
    if (strict ? !(m1[i] > tol) : !(m1[i] >= -tol)) return 0;
    if (strict ? !(m2[i] > t2) : !(m2[i] >= -t2)) return 0;
  }
  return strict ? det > t3 : det >= -t3;
}

// an inertia about the com is physical when it is positive definite and its principal moments
// obey the triangle inequality, i.e. when Sigma = tr(I)/2 - I (the second moment of the mass
// distribution) is positive semidefinite; both tests are frame-independent
static int inertia_ok(const sd_real I[6]) {
  sd_real trace = I[0] + I[1] + I[2];
  sd_real tol = SD_R(1e3) * SD_EPS * trace;
  sd_real half = SD_R(0.5) * trace;
  sd_real sigma[6] = {half - I[0], half - I[1], half - I[2], -I[3], -I[4], -I[5]};
  return trace > 0 && symmetric_definite(I, tol, 1) && symmetric_definite(sigma, tol, 0);
}

int sd_model_setup(sd_model* m, int* bad_body) {
  int dummy;
  if (!bad_body) {
    bad_body = &dummy;
  }
  *bad_body = -1;
  if (m->nbody < 1 || m->nbody > SD_MAX_BODY || m->ndof < 0 || m->ndof > SD_MAX_DOF) {
    return SD_ERR_SIZE;
  }
  if (!sd_allfinite(m->gravity, 3)) {
    return SD_ERR_NONFINITE;
  }

  // tree and joints: parents first, dofs numbered consecutively in body order
  int nextdof = 0;
  for (int i = 0; i < m->nbody; i++) {
    *bad_body = i;
    if (m->body_parent[i] < -1 || m->body_parent[i] >= i) {
      return SD_ERR_PARENT;
    }
    int nd = m->body_dofnum[i];
    int free = m->free_root && i == 0;
    if (free && (nd != 6 || m->body_parent[0] != -1)) {
      return SD_ERR_FREE;
    }
    if ((!free && (nd < 0 || nd > SD_MAX_JOINT_DOF)) || m->body_dofadr[i] != nextdof ||
        nextdof + nd > m->ndof) {
      return SD_ERR_DOFNUM;
    }
    if (m->body_ball[i] && (nd != 3 || free)) {
      return SD_ERR_BALL;
    }
    if (!sd_allfinite(m->body_pos[i], 3) || !sd_allfinite(&m->body_mass[i], 1) ||
        !sd_allfinite(m->body_com[i], 3) || !sd_allfinite(m->body_inertia[i], 6)) {
      return SD_ERR_NONFINITE;
    }
    if (!rotation_ok(m->body_rot[i])) {
      return SD_ERR_ROTATION;
    }
    for (int k = 0; k < nd && !free; k++) {
      const sd_real* D = m->dof_rot[nextdof + k];
      if (!rotation_ok(D)) {
        return SD_ERR_ROTATION;
      }
      if (k == 0 && !is_identity(D)) {
        return SD_ERR_FIRSTDOF;
      }
    }
    nextdof += nd;
    if (!(m->body_mass[i] > 0)) {
      return SD_ERR_MASS;
    }
    if (!inertia_ok(m->body_inertia[i])) {
      return SD_ERR_INERTIA;
    }
  }
  if (nextdof != m->ndof) {
    *bad_body = -1;
    return SD_ERR_DOFNUM;
  }

  // armatures: finite and not negative, named by the body whose joint has the dof
  for (int i = 0; i < m->nbody; i++) {
    *bad_body = i;
    for (int j = m->body_dofadr[i]; j < m->body_dofadr[i] + m->body_dofnum[i]; j++) {
      if (!sd_allfinite(&m->dof_armature[j], 1) || m->dof_armature[j] < 0) {
        return SD_ERR_ARMATURE;
      }
    }
  }
  *bad_body = -1;

  // derived constants: coordinate addresses (a free root's quaternion takes one more),
  // first moment, inertia about the origin, transposed rotations
  int extra = m->free_root ? 1 : 0;
  for (int i = 0; i < m->nbody; i++) {
    m->body_qadr[i] = m->body_dofadr[i] + (i > 0 ? extra : 0);
    extra += m->body_ball[i];
  }
  m->nq = m->ndof + extra;
  for (int i = 0; i < m->nbody; i++) {
    sd_real mass = m->body_mass[i];
    const sd_real* c = m->body_com[i];
    const sd_real* Ic = m->body_inertia[i];
    sd_real* I0 = m->body_inertia0[i];
    for (int k = 0; k < 3; k++) {
      m->body_mcom[i][k] = mass * c[k];
    }
    I0[0] = Ic[0] + mass*(c[1]*c[1] + c[2]*c[2]);
    I0[1] = Ic[1] + mass*(c[0]*c[0] + c[2]*c[2]);
    I0[2] = Ic[2] + mass*(c[0]*c[0] + c[1]*c[1]);
    I0[3] = Ic[3] - mass*c[0]*c[1];
    I0[4] = Ic[4] - mass*c[0]*c[2];
    I0[5] = Ic[5] - mass*c[1]*c[2];
    for (int r = 0; r < 3; r++) {
      for (int k = 0; k < 3; k++) {
        m->body_rotT[i][3*r + k] = m->body_rot[i][3*k + r];
      }
    }
    m->body_ident[i] = is_identity(m->body_rot[i]);
  }
  for (int j = 0; j < m->ndof; j++) {
    for (int r = 0; r < 3; r++) {
      for (int k = 0; k < 3; k++) {
        m->dof_rotT[j][3*r + k] = m->dof_rot[j][3*k + r];
      }
    }
  }
  return SD_OK;
}

const char* sd_strerror(int code) {
  switch (code) {
    case SD_OK:            return "ok";
    case SD_ERR_SIZE:      return "number of bodies or dofs outside the compile-time limits";
    case SD_ERR_PARENT:    return "parent must be -1 (base) or an earlier body";
    case SD_ERR_DOFNUM:    return "a joint has more than 3 dofs or dof addresses are not consecutive";
    case SD_ERR_NONFINITE: return "a NaN or infinite number in the model";
    case SD_ERR_ROTATION:  return "a fixed rotation is not orthonormal with determinant +1";
    case SD_ERR_MASS:      return "mass must be positive";
    case SD_ERR_INERTIA:   return "inertia must be positive definite and obey the triangle inequality";
    case SD_ERR_FIRSTDOF:  return "the first dof of a joint must have an identity dof_rot";
    case SD_ERR_FREE:      return "a free root must be body 0, on the base, with 6 dofs";
    case SD_ERR_BALL:      return "a ball joint has exactly 3 dofs and is not the free root";
    case SD_ERR_ARMATURE:  return "an armature must be a finite number >= 0";
    default:               return "unknown error";
  }
}

//---------------------------------- primitives ---------------------------------------------------

static void diagonal(sd_real inertia[6], sd_real xx, sd_real yy, sd_real zz) {
  inertia[0] = xx; inertia[1] = yy; inertia[2] = zz;
  inertia[3] = inertia[4] = inertia[5] = 0;
}

int sd_inertia_cylinder(sd_real mass, sd_real radius, sd_real length, sd_real inertia[6]) {
  if (!(mass > 0 && radius > 0 && length > 0)) {
    return -1;
  }
  sd_real side = mass * (SD_R(3)*radius*radius + length*length) / SD_R(12);
  diagonal(inertia, side, side, SD_R(0.5) * mass * radius * radius);
  return 0;
}

int sd_inertia_sphere(sd_real mass, sd_real radius, sd_real inertia[6]) {
  if (!(mass > 0 && radius > 0)) {
    return -1;
  }
  sd_real moment = SD_R(0.4) * mass * radius * radius;
  diagonal(inertia, moment, moment, moment);
  return 0;
}

int sd_inertia_ellipsoid(sd_real mass, sd_real a, sd_real b, sd_real c, sd_real inertia[6]) {
  if (!(mass > 0 && a > 0 && b > 0 && c > 0)) {
    return -1;
  }
  sd_real k = mass / SD_R(5);
  diagonal(inertia, k*(b*b + c*c), k*(a*a + c*c), k*(a*a + b*b));
  return 0;
}

// A frustum of radii r0 (z = 0) and r1 (z = L) is a stack of discs of radius r(z) = r0 + (r1-r0)z/L.
// With the moments M_n = integral of r(z)^n z^k dz, volume V = pi M_2, the axial moment is
// rho pi/2 integral r^4, the transverse one rho pi integral (r^4/4 + r^2 z^2); all in closed form.
int sd_inertia_frustum(sd_real mass, sd_real r0, sd_real r1, sd_real length,
                       sd_real* com_z, sd_real inertia[6]) {
  if (!(mass > 0 && r0 > 0 && r1 > 0 && length > 0)) {
    return -1;
  }
  sd_real L = length;
  // integrals over z in [0, L] of r^2, r^2 z, r^2 z^2, r^4 (in units that cancel with the mass)
  sd_real a = r0, b = r1;
  sd_real i_r2 = L * (a*a + a*b + b*b) / SD_R(3);
  sd_real i_r2z = L*L * (a*a + SD_R(2)*a*b + SD_R(3)*b*b) / SD_R(12);
  sd_real i_r2z2 = L*L*L * (a*a + SD_R(3)*a*b + SD_R(6)*b*b) / SD_R(30);
  sd_real i_r4 = L * (a*a*a*a + a*a*a*b + a*a*b*b + a*b*b*b + b*b*b*b) / SD_R(5);
  sd_real zc = i_r2z / i_r2;
  sd_real per = mass / i_r2;  // mass per unit of the r^2 integral (the pi and density cancel)
  sd_real axial = SD_R(0.5) * per * i_r4;
  sd_real transverse0 = per * (SD_R(0.25) * i_r4 + i_r2z2);  // about the z = 0 end
  *com_z = zc;
  diagonal(inertia, transverse0 - mass*zc*zc, transverse0 - mass*zc*zc, axial);
  return 0;
}
