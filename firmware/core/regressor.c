// regressor.c: the joint-torque regressor Y(q, qd, qdd) of the inertial parameters, tau = Y pi
// (without armature and external wrenches), by the spatial form (Atkeson, An and Hollerbach
// 1986; Pinocchio's computeJointTorqueRegressor): one forward pass gives each body's motion and
// its body regressor A_i (the wrench is linear in the body's 10 parameters, f_i = A_i pi_i),
// one column at a time so that the stack holds one wrench; body i then enters the row of every
// dof between the base and it as S' X' A_i, the column carried inwards joint by joint as the
// backward pass of sd_rnea carries a wrench.
//
// A body's parameters, in Pinocchio's order (Inertia::toDynamicParameters):
//   pi_i = (m, h_x, h_y, h_z, I_xx, I_xy, I_yy, I_xz, I_yz, I_zz)
// with h = m c the first moment and I the inertia about the body origin, both in the core's
// body frame: exactly body_mass, body_mcom and body_inertia0 of sd_model.
#include "servodyn.h"
#include "sd_joint.h"
#include "sd_spatial.h"

// Column c of the body regressor: the wrench (n; f) the body needs, about its origin, per unit
// of parameter c: f = m a + dw x h + w x (w x h), n = I dw + w x I w + h x a.
static void body_regressor_column(const sd_real w[3], const sd_real dw[3], const sd_real a[3],
                                  int c, sd_real n[3], sd_real f[3]) {
  sd_zero3(n);
  sd_zero3(f);
  if (c == 0) {
    // mass: f = a
    sd_copy3(f, a);
  } else if (c < 4) {
    // first moment h = e: f = dw x e + w x (w x e), n = e x a
    sd_real e[3] = {0, 0, 0}, wxe[3];
    e[c - 1] = 1;
    sd_cross(wxe, w, e);
    sd_cross(f, w, wxe);
    sd_addcross(f, dw, e);
    sd_cross(n, e, a);
  } else {
    // inertia about the origin, the unit symmetric E of entry (r, k) in the order xx, xy, yy,
    // xz, yz, zz: n = E dw + w x E w, with E v = v_k at row r and v_r at row k
    static const int row_of[6] = {0, 0, 1, 0, 1, 2}, col_of[6] = {0, 1, 1, 2, 2, 2};
    int r = row_of[c - 4], k = col_of[c - 4];
    sd_real Ew[3] = {0, 0, 0};
    n[r] += dw[k];
    Ew[r] += w[k];
    if (r != k) {
      n[k] += dw[r];
      Ew[k] += w[r];
    }
    sd_addcross(n, w, Ew);
  }
}

void sd_regressor(const sd_model* m, sd_data* d, const sd_real* q, const sd_real* qd,
                  const sd_real* qdd, sd_real* Y) {
  const int ncol = SD_NPARAM * m->nbody;
  for (int k = 0; k < m->ndof * ncol; k++) {
    Y[k] = 0;
  }

  // forward pass: each body's motion, then each of its columns carried to the base
  for (int i = 0; i < m->nbody; i++) {
    sd_body_motion(m, d, i, q, qd, qdd, m->body_dofnum[i]);
    for (int c = 0; c < SD_NPARAM; c++) {
      sd_real n[3], f[3];
      body_regressor_column(d->body_w[i], d->body_dw[i], d->body_acc[i], c, n, f);
      sd_real* y = Y + SD_NPARAM * i + c;

      // at joint j, from j = i inwards: each of j's dofs takes its part, then the wrench is
      // handed to the parent, (n; f) <- X' (n; f)
      for (int j = i; j >= 0; j = m->body_parent[j]) {
        int adr = m->body_dofadr[j], nd = m->body_dofnum[j];
        if (nd == 6) {
          // a free root: its whole wrench, force first, then moment
          for (int r = 0; r < 3; r++) {
            y[(adr + r) * ncol] = f[r];
            y[(adr + 3 + r) * ncol] = n[r];
          }
        } else {
          for (int k = adr; k < adr + nd; k++) {
            y[k * ncol] = sd_dot(n, d->dof_axis[k]);
          }
        }
        if (m->body_parent[j] >= 0) {
          sd_real np[3] = {0, 0, 0}, fp[3] = {0, 0, 0};
          sd_addto_xtforce(np, fp, d->body_R[j], m->body_pos[j], n, f);
          sd_copy3(n, np);
          sd_copy3(f, fp);
        }
      }
    }
  }
}
