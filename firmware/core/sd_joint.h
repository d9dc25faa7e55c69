// sd_joint.h (internal): the kinematics of one joint and its body's motion, shared by sd_rnea,
// sd_forward and sd_regressor.
#ifndef SD_JOINT_H
#define SD_JOINT_H

#include "servodyn.h"
#include "sd_math.h"

// world_R_body of the unit quaternion (x, y, z, w); a quaternion off unit length by rounding is
// normalized on the way (the factor 2 / |quat|^2)
static inline void sd_quat_to_rot(sd_real R[9], const sd_real* quat) {
  sd_real x = quat[0], y = quat[1], z = quat[2], w = quat[3];
  sd_real s = SD_R(2) / (x*x + y*y + z*z + w*w);
  R[0] = SD_R(1) - s*(y*y + z*z); R[1] = s*(x*y - z*w);            R[2] = s*(x*z + y*w);
  R[3] = s*(x*y + z*w);            R[4] = SD_R(1) - s*(x*x + z*z); R[5] = s*(y*z - x*w);
  R[6] = s*(x*z - y*w);            R[7] = s*(y*z + x*w);            R[8] = SD_R(1) - s*(x*x + y*y);
}

// The joint's transform and motion axes, as spatial_v2's jcalc: body_R_parent of body i at q
// and the axes of its dofs in the body frame. nd is the joint's dof count, 6 for a free root;
// callers that unroll per joint size pass it as a literal.
// A hinge joint's dof frames are chained: parent_R_body = body_rot Rz(q1) dof_rot2 Rz(q2) dof_rot3
// Rz(q3), so body_R_parent is built from the last dof inwards by pre-multiplying Rz(qk)' dof_rotk'.
static inline void sd_joint_kinematics(const sd_model* m, sd_data* d, int i, const sd_real* q,
                                       const int nd) {
  int adr = m->body_dofadr[i];
  sd_real* R = d->body_R[i];

  // a free root: the transpose of its quaternion's world_R_body; its dofs need no axes
  if (nd == 6) {
    sd_real Rw[9];
    sd_quat_to_rot(Rw, q + m->body_qadr[i] + 3);
    for (int r = 0; r < 3; r++) {
      for (int c = 0; c < 3; c++) {
        R[3*r + c] = Rw[3*c + r];
      }
    }
    return;
  }
  q += m->body_qadr[i] - adr;  // q[adr + k] is then the k-th coordinate of this joint

  // a welded body: the fixed rotation alone
  if (nd == 0) {
    for (int k = 0; k < 9; k++) {
      R[k] = m->body_rotT[i][k];
    }
    return;
  }

  // a ball joint: parent_R_body = body_rot R(quat), and its dofs turn about the body's axes
  if (m->body_ball[i]) {
    sd_real Rq[9];
    sd_quat_to_rot(Rq, q + adr);
    for (int r = 0; r < 3; r++) {
      for (int c = 0; c < 3; c++) {
        R[3*r + c] = Rq[r]*m->body_rotT[i][c] + Rq[3 + r]*m->body_rotT[i][3 + c] +
                     Rq[6 + r]*m->body_rotT[i][6 + c];
        d->dof_axis[adr + r][c] = (r == c) ? SD_R(1) : SD_R(0);
      }
    }
    return;
  }

  // first dof: R = Rz(q1)' body_rot'
  sd_real c = sd_cos(q[adr]), s = sd_sin(q[adr]);
  if (m->body_ident[i]) {
    R[0] = c;  R[1] = s; R[2] = 0;
    R[3] = -s; R[4] = c; R[5] = 0;
    R[6] = 0;  R[7] = 0; R[8] = 1;
  } else {
    sd_rotz_t_mul(R, c, s, m->body_rotT[i]);
  }
  d->dof_axis[adr][0] = 0;
  d->dof_axis[adr][1] = 0;
  d->dof_axis[adr][2] = 1;

  // further dofs: B = Rz(qk)' dof_rotk' maps the previous dof frame into this one
  for (int k = 1; k < nd; k++) {
    int j = adr + k;
    sd_real B[9], prev[9];
    c = sd_cos(q[j]);
    s = sd_sin(q[j]);
    sd_rotz_t_mul(B, c, s, m->dof_rotT[j]);
    for (int e = 0; e < 9; e++) {
      prev[e] = R[e];
    }
    sd_mulmm(R, B, prev);
    for (int l = adr; l < j; l++) {
      sd_mulmv(d->dof_axis[l], B, d->dof_axis[l]);
    }
    d->dof_axis[j][0] = 0;
    d->dof_axis[j][1] = 0;
    d->dof_axis[j][2] = 1;
  }
}

// Add the motion of body i's nd-dof joint to the motion w, dw, a it inherits from its parent.
static inline void sd_joint_motion(const sd_model* m, const sd_data* d, int i, const int nd,
                                   const sd_real* qd, const sd_real* qdd, sd_real* w,
                                   sd_real* dw, sd_real* a) {
  int adr = m->body_dofadr[i];

  // a ball joint, or a free root's rotation: the dofs are the body-frame rate itself,
  // dw += qdd + w x qd, w += qd
  if (nd == 6 || m->body_ball[i]) {
    int rot = nd == 6 ? adr + 3 : adr;
    sd_addto3(dw, qdd + rot);
    sd_addcross(dw, w, qd + rot);
    sd_addto3(w, qd + rot);

    // a free root's translation: its origin accelerates by qdd_lin + w x v
    if (nd == 6) {
      sd_addto3(a, qdd + adr);
      sd_addcross(a, w, qd + adr);
    }
    return;
  }

  // hinges, dof by dof: dw += z qdd + w x z qd, then w += z qd
  for (int j = adr; j < adr + nd; j++) {
    const sd_real* z = d->dof_axis[j];
    sd_real zqd[3];
    sd_scl3(zqd, z, qd[j]);
    sd_addtoscl3(dw, z, qdd[j]);
    sd_addcross(dw, w, zqd);
    sd_addto3(w, zqd);
  }
}

// One step of the forward pass of sd_rnea and sd_regressor: body i's joint kinematics (body_R,
// dof_axis) and its motion (body_w, body_dw, body_acc) from its parent's, which must be done.
// The base accelerates upwards at -g, so gravity needs no per-body term.
static inline void sd_body_motion(const sd_model* m, sd_data* d, int i, const sd_real* q,
                                  const sd_real* qd, const sd_real* qdd, const int nd) {
  static const sd_real zero[3] = {0, 0, 0};
  int parent = m->body_parent[i];
  sd_real base_acc[3] = {-m->gravity[0], -m->gravity[1], -m->gravity[2]};
  const sd_real* wp = parent < 0 ? zero : d->body_w[parent];
  const sd_real* dwp = parent < 0 ? zero : d->body_dw[parent];
  const sd_real* ap = parent < 0 ? base_acc : d->body_acc[parent];
  const sd_real* p = m->body_pos[i];
  sd_real* w = d->body_w[i];
  sd_real* dw = d->body_dw[i];
  sd_real* a = d->body_acc[i];

  // joint transform and dof axes
  sd_joint_kinematics(m, d, i, q, nd);
  const sd_real* R = d->body_R[i];

  // the parent's motion at the body origin: w = R w_p, dw = R dw_p and
  // a = R (a_p + dw_p x p + w_p x (w_p x p))
  sd_real wxp[3], t[3];
  sd_cross(wxp, wp, p);
  sd_cross(t, wp, wxp);
  sd_addcross(t, dwp, p);
  sd_addto3(t, ap);
  sd_mulmv(a, R, t);
  sd_mulmv(w, R, wp);
  sd_mulmv(dw, R, dwp);

  // plus the joint's own
  sd_joint_motion(m, d, i, nd, qd, qdd, w, dw, a);
}

// the wrench (moment about the origin, force), body 0 frame, of the root force in d
static inline void sd_root_wrench(const sd_data* d, sd_real wrench[6]) {
  sd_mulmv(wrench + 3, d->body_R[0], d->root_force);
  sd_cross(wrench, d->root_point, wrench + 3);
}

#endif  // SD_JOINT_H
