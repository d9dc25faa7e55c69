// bench.cpp: check servodyn against Pinocchio and MuJoCo on one model, then time all three,
// interleaved.
//
// usage: bench [--strict] [--check K] [--reps R] [--mjcf OUT.xml] MODEL.bin STATES.bin
//   MODEL.bin   the raw bytes of one sd_model (double build, after sd_model_setup)
//   STATES.bin  int32 N, int32 ndof, then N*ndof doubles each of q, qd, qdd, tau (row-major)
//   --strict    exit with status 3 when any relative disagreement exceeds 1e-8
//   --check K   compare the three libraries on the first K states (default 10)
//   --reps R    timed repetitions, each one pass of every call over all N states (default 21);
//               the medians of the times and of servodyn's per-repetition ratios are reported
//   --mjcf OUT  also write the generated MJCF, for timing MuJoCo from Python on the same model
//
// The same model is built in Pinocchio (a chain of RZ joints per servodyn joint) and in MuJoCo
// (generated MJCF, up to 3 hinges per body). One JSON object goes to stdout; problems go to stderr.
// Its "ratio" member holds servodyn's time over Pinocchio's and over MuJoCo's: median, quartiles
// and range over the repetitions, each ratio taken within one repetition.

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <functional>
#include <sstream>
#include <string>
#include <vector>

#include <time.h>

#include <Eigen/Core>
#include <pinocchio/algorithm/aba.hpp>
#include <pinocchio/algorithm/rnea.hpp>

#include <mujoco/mujoco.h>

#include "servodyn.h"

namespace {

const double kTolerance = 1e-8;   // largest accepted relative disagreement
const double kDt = 1e-3;          // integration step of all three RK4 steps
// Pinocchio's aba in the world convention: about 10% faster here than the default local one
const pinocchio::Convention kAbaConvention = pinocchio::Convention::WORLD;

[[noreturn]] void die(const std::string& message) {
  std::fprintf(stderr, "bench: %s\n", message.c_str());
  std::exit(1);
}

//---------------------------------- input files -------------------------------------------------

std::vector<char> read_bytes(const char* path) {
  std::ifstream file(path, std::ios::binary);
  if (!file) die(std::string("cannot open ") + path);
  return std::vector<char>(std::istreambuf_iterator<char>(file), std::istreambuf_iterator<char>());
}

// load the model blob and check it by running sd_model_setup again on a copy
void load_model(const char* path, sd_model* model) {
  std::vector<char> bytes = read_bytes(path);
  if (bytes.size() != sizeof(sd_model)) {
    die(std::string(path) + ": " + std::to_string(bytes.size()) +
        " bytes, but sizeof(sd_model) is " + std::to_string(sizeof(sd_model)) +
        " (double build, SD_MAX_BODY " +
        std::to_string(SD_MAX_BODY) + ", SD_MAX_DOF " + std::to_string(SD_MAX_DOF) + ")");
  }
  std::memcpy(model, bytes.data(), sizeof(sd_model));
  if (model->nbody < 1 || model->nbody > SD_MAX_BODY || model->ndof < 1 ||
      model->ndof > SD_MAX_DOF) {
    die(std::string(path) + ": nbody " + std::to_string(model->nbody) + ", ndof " +
        std::to_string(model->ndof) + ": the benchmark needs 1.." + std::to_string(SD_MAX_BODY) +
        " bodies and 1.." + std::to_string(SD_MAX_DOF) + " dofs");
  }
  static sd_model checked;
  checked = *model;
  int bad_body = -1;
  int code = sd_model_setup(&checked, &bad_body);
  if (code != SD_OK) {
    die(std::string(path) + ": sd_model_setup rejects the model: " + sd_strerror(code) +
        " (body " + std::to_string(bad_body) + ")");
  }
  if (std::memcmp(&checked, model, sizeof(sd_model)) != 0) {
    std::fprintf(stderr, "bench: warning: %s: derived fields differ from a fresh sd_model_setup; "
                 "using the fresh ones\n", path);
    *model = checked;
  }
}

struct States {
  int n = 0, ndof = 0;
  std::vector<double> q, qd, qdd, tau;   // n x ndof each, row-major
};

States load_states(const char* path, int ndof) {
  std::vector<char> bytes = read_bytes(path);
  if (bytes.size() < 8) die(std::string(path) + ": shorter than its 8-byte header");
  int32_t header[2];
  std::memcpy(header, bytes.data(), sizeof header);
  States s;
  s.n = header[0];
  s.ndof = header[1];
  if (s.ndof != ndof) {
    die(std::string(path) + ": ndof " + std::to_string(s.ndof) + " but the model has " +
        std::to_string(ndof));
  }
  if (s.n < 1) die(std::string(path) + ": N = " + std::to_string(s.n) + ", need at least 1");
  size_t count = size_t(s.n) * size_t(s.ndof);
  size_t expected = 8 + 4 * count * sizeof(double);
  if (bytes.size() != expected) {
    die(std::string(path) + ": " + std::to_string(bytes.size()) + " bytes, expected " +
        std::to_string(expected) + " for N " + std::to_string(s.n) + ", ndof " +
        std::to_string(s.ndof));
  }
  std::vector<double>* arrays[4] = {&s.q, &s.qd, &s.qdd, &s.tau};
  for (int a = 0; a < 4; a++) {
    arrays[a]->resize(count);
    std::memcpy(arrays[a]->data(), bytes.data() + 8 + a * count * sizeof(double),
                count * sizeof(double));
  }
  return s;
}

// a number as text, exact by default
std::string num(double x, int digits = 17) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.*g", digits, x);
  return buf;
}

//---------------------------------- rotations ---------------------------------------------------

typedef Eigen::Matrix<double, 3, 3, Eigen::RowMajor> Mat3;

Mat3 mat3(const double* r) { return Mat3(Eigen::Map<const Mat3>(r)); }

// unit quaternion (w, x, y, z) of a rotation matrix, Shepperd's method
Eigen::Vector4d quat_from_mat(const Mat3& r) {
  double trace = r.trace();
  Eigen::Vector4d q;
  if (trace > 0) {
    double s = 2 * std::sqrt(1 + trace);
    q << s / 4, (r(2, 1) - r(1, 2)) / s, (r(0, 2) - r(2, 0)) / s, (r(1, 0) - r(0, 1)) / s;
  } else if (r(0, 0) > r(1, 1) && r(0, 0) > r(2, 2)) {
    double s = 2 * std::sqrt(1 + r(0, 0) - r(1, 1) - r(2, 2));
    q << (r(2, 1) - r(1, 2)) / s, s / 4, (r(0, 1) + r(1, 0)) / s, (r(0, 2) + r(2, 0)) / s;
  } else if (r(1, 1) > r(2, 2)) {
    double s = 2 * std::sqrt(1 + r(1, 1) - r(0, 0) - r(2, 2));
    q << (r(0, 2) - r(2, 0)) / s, (r(0, 1) + r(1, 0)) / s, s / 4, (r(1, 2) + r(2, 1)) / s;
  } else {
    double s = 2 * std::sqrt(1 + r(2, 2) - r(0, 0) - r(1, 1));
    q << (r(1, 0) - r(0, 1)) / s, (r(0, 2) + r(2, 0)) / s, (r(1, 2) + r(2, 1)) / s, s / 4;
  }
  return q / q.norm();
}

//---------------------------------- pinocchio model ---------------------------------------------

// one RZ joint per dof; the body inertia goes on the joint of its last dof, or, for a 0-dof body,
// on the joint its frame is welded to, with the fixed placement
pinocchio::Model build_pinocchio(const sd_model* m) {
  pinocchio::Model model;
  std::vector<pinocchio::JointIndex> frame_joint(m->nbody);  // joint each body frame rides on
  std::vector<pinocchio::SE3> frame_place(m->nbody);         // body frame in that joint frame
  for (int i = 0; i < m->nbody; i++) {
    int parent = m->body_parent[i];
    pinocchio::JointIndex parent_joint = parent < 0 ? 0 : frame_joint[parent];
    pinocchio::SE3 parent_place = parent < 0 ? pinocchio::SE3::Identity() : frame_place[parent];
    pinocchio::SE3 joint_place =
        parent_place * pinocchio::SE3(mat3(m->body_rot[i]), Eigen::Vector3d(m->body_pos[i]));
    pinocchio::Inertia inertia(
        m->body_mass[i], Eigen::Vector3d(m->body_com[i]),
        (Eigen::Matrix3d() << m->body_inertia[i][0], m->body_inertia[i][3], m->body_inertia[i][4],
         m->body_inertia[i][3], m->body_inertia[i][1], m->body_inertia[i][5],
         m->body_inertia[i][4], m->body_inertia[i][5], m->body_inertia[i][2]).finished());

    // 0-dof body: weld it to the parent's joint
    if (m->body_dofnum[i] == 0) {
      frame_joint[i] = parent_joint;
      frame_place[i] = joint_place;
      model.appendBodyToJoint(parent_joint, inertia, joint_place);
      continue;
    }

    // moving body: a chain of RZ joints; later dofs sit at dof_rot with no translation
    pinocchio::JointIndex joint = parent_joint;
    for (int k = 0; k < m->body_dofnum[i]; k++) {
      int dof = m->body_dofadr[i] + k;
      pinocchio::SE3 place =
          k == 0 ? joint_place : pinocchio::SE3(mat3(m->dof_rot[dof]), Eigen::Vector3d::Zero());
      joint = model.addJoint(joint, pinocchio::JointModelRZ(), place,
                             "b" + std::to_string(i) + "_d" + std::to_string(k));
      if (model.joints[joint].idx_v() != dof) {
        die("pinocchio dof order differs from servodyn at body " + std::to_string(i));
      }
    }
    model.appendBodyToJoint(joint, inertia, pinocchio::SE3::Identity());
    frame_joint[i] = joint;
    frame_place[i] = pinocchio::SE3::Identity();
  }
  model.gravity.linear(Eigen::Vector3d(m->gravity));
  if (model.nv != m->ndof || model.nq != m->ndof) die("pinocchio model has the wrong size");
  return model;
}

//---------------------------------- mujoco model ------------------------------------------------

// one <body> per servodyn body with frame Q = body_rot*D2*D3 and hinge axes (D2*D3)'z, D3'z, z,
// so that the MuJoCo body frame is the servodyn body frame
void mjcf_body(const sd_model* m, int i, const std::vector<std::vector<int>>& children,
               std::ostringstream& xml, int depth) {
  std::string pad(2 * depth + 4, ' ');
  int nd = m->body_dofnum[i], adr = m->body_dofadr[i];
  Mat3 tail = Mat3::Identity();   // D2*D3 product of the joint's fixed dof rotations
  for (int k = 1; k < nd; k++) tail = tail * mat3(m->dof_rot[adr + k]);
  Mat3 frame = mat3(m->body_rot[i]) * tail;
  Eigen::Vector4d quat = quat_from_mat(frame);
  xml << pad << "<body name=\"b" << i << "\" pos=\"" << num(m->body_pos[i][0]) << " "
      << num(m->body_pos[i][1]) << " " << num(m->body_pos[i][2]) << "\" quat=\"" << num(quat[0])
      << " " << num(quat[1]) << " " << num(quat[2]) << " " << num(quat[3]) << "\">\n";
  const double* inertia = m->body_inertia[i];
  xml << pad << "  <inertial pos=\"" << num(m->body_com[i][0]) << " " << num(m->body_com[i][1])
      << " " << num(m->body_com[i][2]) << "\" mass=\"" << num(m->body_mass[i])
      << "\" fullinertia=\"" << num(inertia[0]) << " " << num(inertia[1]) << " "
      << num(inertia[2]) << " " << num(inertia[3]) << " " << num(inertia[4]) << " "
      << num(inertia[5]) << "\"/>\n";
  for (int k = 0; k < nd; k++) {
    Mat3 after = Mat3::Identity();   // fixed rotations after dof k: D_{k+1}*...*D_nd
    for (int j = k + 1; j < nd; j++) after = after * mat3(m->dof_rot[adr + j]);
    Eigen::Vector3d axis = after.transpose() * Eigen::Vector3d::UnitZ();
    xml << pad << "  <joint name=\"j" << i << "_" << k << "\" type=\"hinge\" axis=\""
        << num(axis[0]) << " " << num(axis[1]) << " " << num(axis[2]) << "\"/>\n";
  }
  for (int child : children[i]) mjcf_body(m, child, children, xml, depth + 1);
  xml << pad << "</body>\n";
}

std::string mjcf_text(const sd_model* m) {
  std::vector<std::vector<int>> children(m->nbody);
  std::vector<int> roots;
  for (int i = 0; i < m->nbody; i++) {
    (m->body_parent[i] < 0 ? roots : children[m->body_parent[i]]).push_back(i);
  }
  std::ostringstream xml;
  xml << "<mujoco model=\"servodyn\">\n"
      << "  <compiler angle=\"radian\" inertiafromgeom=\"false\"/>\n"
      << "  <option timestep=\"" << num(kDt) << "\" integrator=\"RK4\" gravity=\""
      << num(m->gravity[0]) << " " << num(m->gravity[1]) << " " << num(m->gravity[2]) << "\">\n"
      << "    <flag contact=\"disable\" constraint=\"disable\" autoreset=\"disable\"/>\n"
      << "  </option>\n"
      << "  <worldbody>\n";
  for (int root : roots) mjcf_body(m, root, children, xml, 0);
  xml << "  </worldbody>\n</mujoco>\n";
  return xml.str();
}

// load the MJCF from a VFS buffer; dof_map[k] is the MuJoCo dof of servodyn dof k
mjModel* build_mujoco(const sd_model* m, std::vector<int>* dof_map) {
  if (mj_version() != mjVERSION_HEADER) die("libmujoco version differs from mujoco.h");
  std::string xml = mjcf_text(m);
  mjVFS vfs;
  mj_defaultVFS(&vfs);
  if (mj_addBufferVFS(&vfs, "servodyn.xml", xml.data(), int(xml.size())) != 0) {
    die("cannot add the MJCF to the MuJoCo VFS");
  }
  char error[1000] = "";
  mjModel* model = mj_loadXML("servodyn.xml", &vfs, error, sizeof error);
  mj_deleteVFS(&vfs);
  if (!model) die(std::string("MuJoCo rejects the generated MJCF: ") + error + "\n" + xml);
  if (model->nv != m->ndof || model->nq != m->ndof) die("MuJoCo model has the wrong size");

  // map servodyn dofs to MuJoCo dofs by joint name (MuJoCo numbers bodies depth-first)
  dof_map->assign(m->ndof, -1);
  for (int i = 0; i < m->nbody; i++) {
    for (int k = 0; k < m->body_dofnum[i]; k++) {
      std::string name = "j" + std::to_string(i) + "_" + std::to_string(k);
      int joint = mj_name2id(model, mjOBJ_JOINT, name.c_str());
      if (joint < 0 || model->jnt_qposadr[joint] != model->jnt_dofadr[joint]) {
        die("MuJoCo joint " + name + " missing or with qpos and dof addresses apart");
      }
      (*dof_map)[m->body_dofadr[i] + k] = model->jnt_dofadr[joint];
    }
  }
  return model;
}

//---------------------------------- one evaluation of each library ------------------------------

typedef Eigen::Map<const Eigen::VectorXd> CVec;

// the three libraries with their work memory
struct Libraries {
  // declaration order is initialisation order: build_mujoco fills dof_map before mj_m is set
  int n;
  const sd_model* sd_m;
  sd_data* sd_d;
  pinocchio::Model pin_m;
  pinocchio::Data pin_d;
  std::vector<int> dof_map;   // servodyn dof -> MuJoCo dof
  mjModel* mj_m;
  mjData* mj_d;
  // RK4 stage vectors of the Pinocchio step
  Eigen::VectorXd q_stage, v_stage, k_q, k_v;

  Libraries(const sd_model* m)
      : n(m->ndof), sd_m(m), sd_d(new sd_data()), pin_m(build_pinocchio(m)), pin_d(pin_m),
        mj_m(build_mujoco(m, &dof_map)), mj_d(mj_makeData(mj_m)),
        q_stage(n), v_stage(n), k_q(n), k_v(n) {
    if (!mj_d) die("mj_makeData failed");
  }
  ~Libraries() {
    mj_deleteData(mj_d);
    mj_deleteModel(mj_m);
    delete sd_d;
  }

  // copy a servodyn-ordered vector into a MuJoCo one, and back
  void to_mj(const double* src, mjtNum* dst) const {
    for (int k = 0; k < n; k++) dst[dof_map[k]] = src[k];
  }
  void from_mj(const mjtNum* src, double* dst) const {
    for (int k = 0; k < n; k++) dst[k] = src[dof_map[k]];
  }

  void sd_inverse(const double* q, const double* qd, const double* qdd, double* tau) {
    sd_rnea(sd_m, sd_d, q, qd, qdd, nullptr, tau);
  }
  void sd_direct(const double* q, const double* qd, const double* tau, double* qdd) {
    sd_forward(sd_m, sd_d, q, qd, tau, nullptr, qdd);
  }
  void sd_rk4(double* q, double* qd, const double* tau) {
    sd_step(sd_m, sd_d, q, qd, tau, nullptr, kDt, SD_RK4);
  }

  const Eigen::VectorXd& pin_inverse(const double* q, const double* qd, const double* qdd) {
    return pinocchio::rnea(pin_m, pin_d, CVec(q, n), CVec(qd, n), CVec(qdd, n));
  }
  const Eigen::VectorXd& pin_direct(const double* q, const double* qd, const double* tau) {
    return pinocchio::aba(pin_m, pin_d, CVec(q, n), CVec(qd, n), CVec(tau, n), kAbaConvention);
  }
  // classical RK4 on (q, qd) from four aba calls; all joints are revolute, so q += dt * qd
  void pin_rk4(double* q_io, double* qd_io, const double* tau_in) {
    Eigen::Map<Eigen::VectorXd> q(q_io, n), v(qd_io, n);
    CVec tau(tau_in, n);
    const double stage_dt[3] = {kDt / 2, kDt / 2, kDt};
    const double weight[4] = {kDt / 6, kDt / 3, kDt / 3, kDt / 6};
    const Eigen::VectorXd* acc = &pinocchio::aba(pin_m, pin_d, q, v, tau, kAbaConvention);
    k_q = weight[0] * v;
    k_v = weight[0] * *acc;
    v_stage = v;
    for (int s = 0; s < 3; s++) {
      q_stage = q + stage_dt[s] * v_stage;
      v_stage = v + stage_dt[s] * *acc;
      acc = &pinocchio::aba(pin_m, pin_d, q_stage, v_stage, tau, kAbaConvention);
      k_q += weight[s + 1] * v_stage;
      k_v += weight[s + 1] * *acc;
    }
    q += k_q;
    v += k_v;
  }

  const mjtNum* mj_inv(const double* q, const double* qd, const double* qdd) {
    to_mj(q, mj_d->qpos);
    to_mj(qd, mj_d->qvel);
    to_mj(qdd, mj_d->qacc);
    mj_inverse(mj_m, mj_d);
    return mj_d->qfrc_inverse;
  }
  const mjtNum* mj_fwd(const double* q, const double* qd, const double* tau) {
    to_mj(q, mj_d->qpos);
    to_mj(qd, mj_d->qvel);
    to_mj(tau, mj_d->qfrc_applied);
    mj_forward(mj_m, mj_d);
    return mj_d->qacc;
  }
  void mj_rk4(const double* q, const double* qd, const double* tau) {
    to_mj(q, mj_d->qpos);
    to_mj(qd, mj_d->qvel);
    to_mj(tau, mj_d->qfrc_applied);
    mj_step(mj_m, mj_d);
  }
};

//---------------------------------- agreement ---------------------------------------------------

// largest absolute and relative (to the larger infinity norm of the pair) difference seen
struct Diff {
  double abs = 0, rel = 0;
  void add(const std::vector<double>& a, const std::vector<double>& b) {
    double diff = 0, scale = 0;
    for (size_t k = 0; k < a.size(); k++) {
      diff = std::max(diff, std::fabs(a[k] - b[k]));
      scale = std::max({scale, std::fabs(a[k]), std::fabs(b[k])});
    }
    abs = std::max(abs, diff);
    rel = std::max(rel, scale > 0 ? diff / scale : 0.0);
  }
  std::string json() const { return "{\"abs\":" + num(abs, 3) + ",\"rel\":" + num(rel, 3) + "}"; }
};

// the pairwise differences of one quantity computed by the three libraries
struct Comparison {
  const char* name;
  Diff sd_pin, sd_mj, pin_mj;
  void add(const std::vector<double>& sd, const std::vector<double>& pin,
           const std::vector<double>& mj) {
    sd_pin.add(sd, pin);
    sd_mj.add(sd, mj);
    pin_mj.add(pin, mj);
  }
  double worst() const { return std::max({sd_pin.rel, sd_mj.rel, pin_mj.rel}); }
  // the library that disagrees with both others 100 times more than they disagree together
  const char* odd_one_out() const {
    if (100 * pin_mj.rel < std::min(sd_pin.rel, sd_mj.rel)) return "servodyn";
    if (100 * sd_mj.rel < std::min(sd_pin.rel, pin_mj.rel)) return "Pinocchio";
    if (100 * sd_pin.rel < std::min(sd_mj.rel, pin_mj.rel)) return "MuJoCo";
    return nullptr;
  }
  std::string json() const {
    return std::string("\"") + name + "\":{\"sd_vs_pin\":" + sd_pin.json() + ",\"sd_vs_mj\":" +
           sd_mj.json() + ",\"pin_vs_mj\":" + pin_mj.json() + "}";
  }
};

// compare inverse dynamics, forward dynamics and one RK4 step (as increments of q and qd,
// so the state itself does not hide the error) on the first states
std::string check_agreement(Libraries& lib, const States& s, int count, bool* ok) {
  int n = s.ndof;
  Comparison inverse{"rnea"}, direct{"forward"}, step{"rk4"};
  std::vector<double> sd(n), pin(n), mj(n);
  std::vector<double> sd_x(2 * n), pin_x(2 * n), mj_x(2 * n);
  for (int i = 0; i < count; i++) {
    const double* q = &s.q[size_t(i) * n];
    const double* qd = &s.qd[size_t(i) * n];
    const double* qdd = &s.qdd[size_t(i) * n];
    const double* tau = &s.tau[size_t(i) * n];

    lib.sd_inverse(q, qd, qdd, sd.data());
    Eigen::Map<Eigen::VectorXd>(pin.data(), n) = lib.pin_inverse(q, qd, qdd);
    lib.from_mj(lib.mj_inv(q, qd, qdd), mj.data());
    inverse.add(sd, pin, mj);

    lib.sd_direct(q, qd, tau, sd.data());
    Eigen::Map<Eigen::VectorXd>(pin.data(), n) = lib.pin_direct(q, qd, tau);
    lib.from_mj(lib.mj_fwd(q, qd, tau), mj.data());
    direct.add(sd, pin, mj);

    std::vector<double> sd_q(q, q + n), sd_qd(qd, qd + n), pin_q(q, q + n), pin_qd(qd, qd + n);
    lib.sd_rk4(sd_q.data(), sd_qd.data(), tau);
    lib.pin_rk4(pin_q.data(), pin_qd.data(), tau);
    lib.mj_rk4(q, qd, tau);
    std::vector<double> mj_q(n), mj_qd(n);
    lib.from_mj(lib.mj_d->qpos, mj_q.data());
    lib.from_mj(lib.mj_d->qvel, mj_qd.data());
    for (int k = 0; k < n; k++) {
      sd_x[k] = sd_q[k] - q[k];
      sd_x[n + k] = sd_qd[k] - qd[k];
      pin_x[k] = pin_q[k] - q[k];
      pin_x[n + k] = pin_qd[k] - qd[k];
      mj_x[k] = mj_q[k] - q[k];
      mj_x[n + k] = mj_qd[k] - qd[k];
    }
    step.add(sd_x, pin_x, mj_x);
  }

  *ok = true;
  for (const Comparison* c : {&inverse, &direct, &step}) {
    if (c->worst() > kTolerance) {
      *ok = false;
      const char* odd = c->odd_one_out();
      std::fprintf(stderr,
                   "bench: WARNING: %s disagrees beyond %g: relative sd-pin %.3g, sd-mj %.3g, "
                   "pin-mj %.3g; %s%s\n",
                   c->name, kTolerance, c->sd_pin.rel, c->sd_mj.rel, c->pin_mj.rel,
                   odd ? odd : "no library stands out (ill-conditioned model or states?)",
                   odd ? " is the odd one out" : "");
    }
  }
  return "{\"states\":" + std::to_string(count) + ",\"tolerance\":" + num(kTolerance) + "," +
         inverse.json() + "," + direct.json() + "," + step.json() +
         ",\"ok\":" + (*ok ? "true" : "false") + "}";
}

//---------------------------------- timing ------------------------------------------------------

volatile double g_sink;   // outputs end here so no call can be optimised away

// one implementation of one quantity; call(i, &sink) evaluates state i
struct Timed {
  const char* name;
  std::function<void(int, double*)> call;
  std::vector<double> us;   // µs of CPU time per call in each repetition
  int descheduled = 0;      // passes during which the thread waited for a core
};

// the servodyn, Pinocchio and MuJoCo implementations of one quantity, timed against each other
struct Contest {
  const char* name;
  Timed impl[3];   // servodyn, Pinocchio, MuJoCo
};

// µs of CPU time this thread has used
double thread_cpu_us() {
  timespec now;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &now);
  return double(now.tv_sec) * 1e6 + double(now.tv_nsec) * 1e-3;
}

// mean µs of CPU time per call of one pass over all states. CPU time, not wall time: on a
// machine with more runnable threads than cores the scheduler takes the core away for
// milliseconds at a time, which wall time would charge to whichever call was running. Such
// passes are counted, to say how busy the machine was.
double time_pass(int nstates, Timed& t, double* sink) {
  auto wall_start = std::chrono::steady_clock::now();
  double cpu_start = thread_cpu_us();
  for (int i = 0; i < nstates; i++) t.call(i, sink);
  double cpu = thread_cpu_us() - cpu_start;
  double wall = std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() -
                                                          wall_start).count();
  if (wall > 1.05 * cpu + 10) t.descheduled++;
  return cpu / nstates;
}

// Times the implementations interleaved: in each repetition, every contest runs its three
// implementations one after the other, one pass over all states each, in the six orders in turn.
// A neighbour that slows the machine for a while then slows the three alike, so their ratio
// within one repetition holds; timing each in its own block of repetitions let it hit one only.
void time_interleaved(int reps, int nstates, std::vector<Contest>& contests) {
  static const int kOrders[6][3] = {{0, 1, 2}, {1, 2, 0}, {2, 0, 1},
                                    {0, 2, 1}, {2, 1, 0}, {1, 0, 2}};
  double sink = 0;
  for (Contest& c : contests) {
    for (Timed& t : c.impl) {
      time_pass(nstates, t, &sink);   // warm-up
      t.us.assign(reps, 0.0);
      t.descheduled = 0;
    }
  }
  for (int r = 0; r < reps; r++) {
    for (Contest& c : contests) {
      for (int k : kOrders[r % 6]) c.impl[k].us[r] = time_pass(nstates, c.impl[k], &sink);
    }
  }
  g_sink = g_sink + sink;
}

// the p-quantile of a sample, interpolated linearly between order statistics (as numpy does)
double quantile(std::vector<double> sample, double p) {
  std::sort(sample.begin(), sample.end());
  double pos = p * double(sample.size() - 1);
  size_t lo = size_t(pos), hi = std::min(lo + 1, sample.size() - 1);
  return sample[lo] + (pos - double(lo)) * (sample[hi] - sample[lo]);
}

// median, quartiles and range of a sample
std::string summary_json(const std::vector<double>& sample) {
  return "{\"median\":" + num(quantile(sample, 0.5), 4) + ",\"q1\":" +
         num(quantile(sample, 0.25), 4) + ",\"q3\":" + num(quantile(sample, 0.75), 4) +
         ",\"min\":" + num(quantile(sample, 0), 4) + ",\"max\":" + num(quantile(sample, 1), 4) +
         "}";
}

std::string list_json(const std::vector<double>& values) {
  std::string out;
  for (double v : values) out += (out.empty() ? "" : ",") + num(v, 4);
  return "[" + out + "]";
}

// The repetitions that ran on a quiet machine: those whose total time is within 10 % of the
// fastest one's. While a neighbour's build keeps the shared host busy, everything here runs up
// to 1.6x slower, servodyn more so than Pinocchio, which shifts the ratios by up to 25 %:
// interleaving cannot cancel that. The quiet repetitions agree from run to run within a few per
// cent, as long as the run saw some quiet time at all.
std::vector<bool> quiet_repetitions(const std::vector<Contest>& contests) {
  size_t reps = contests[0].impl[0].us.size();
  std::vector<double> total(reps, 0.0);
  for (const Contest& c : contests) {
    for (const Timed& t : c.impl) {
      for (size_t r = 0; r < reps; r++) total[r] += t.us[r];
    }
  }
  double fastest = *std::min_element(total.begin(), total.end());
  std::vector<bool> quiet(reps);
  for (size_t r = 0; r < reps; r++) quiet[r] = total[r] <= 1.1 * fastest;
  return quiet;
}

// the JSON members from the timed contests: "us" the median µs per call of each implementation,
// "us_per_rep" every repetition's, "ratio" servodyn's time over Pinocchio's and over MuJoCo's,
// per repetition, summarised by contest, "ratio_quiet" the same over the quiet repetitions only,
// "quiet_reps" their number, and "descheduled" the share of passes during which the thread
// waited for a core
std::string timing_json(const std::vector<Contest>& contests) {
  std::string us, per_rep, ratio, ratio_quiet;
  std::vector<bool> quiet = quiet_repetitions(contests);
  int passes = 0, descheduled = 0;
  for (const Contest& c : contests) {
    for (const Timed& t : c.impl) {
      std::string key = std::string(us.empty() ? "" : ",") + "\"" + t.name + "\":";
      us += key + num(quantile(t.us, 0.5), 4);
      per_rep += key + list_json(t.us);
      passes += int(t.us.size());
      descheduled += t.descheduled;
    }
    std::vector<double> to_pin, to_mj, quiet_to_pin, quiet_to_mj;
    for (size_t r = 0; r < quiet.size(); r++) {
      double pin = c.impl[0].us[r] / c.impl[1].us[r], mj = c.impl[0].us[r] / c.impl[2].us[r];
      to_pin.push_back(pin);
      to_mj.push_back(mj);
      if (quiet[r]) {
        quiet_to_pin.push_back(pin);
        quiet_to_mj.push_back(mj);
      }
    }
    std::string key = std::string(ratio.empty() ? "" : ",") + "\"" + c.name + "\":";
    ratio += key + "{\"pin\":" + summary_json(to_pin) + ",\"mj\":" + summary_json(to_mj) + "}";
    ratio_quiet += key + "{\"pin\":" + summary_json(quiet_to_pin) + ",\"mj\":" +
                   summary_json(quiet_to_mj) + "}";
  }
  return "\"us\":{" + us + "},\"us_per_rep\":{" + per_rep + "},\"ratio\":{" + ratio +
         "},\"ratio_quiet\":{" + ratio_quiet + "},\"quiet_reps\":" +
         std::to_string(std::count(quiet.begin(), quiet.end(), true)) +
         ",\"descheduled\":" + num(double(descheduled) / passes, 3);
}

}  // namespace

int main(int argc, char** argv) {
  // command line
  bool strict = false;
  int check = 10, reps = 21;
  std::vector<const char*> paths;
  const char* mjcf_out = nullptr;
  for (int a = 1; a < argc; a++) {
    std::string arg = argv[a];
    if (arg == "--strict") {
      strict = true;
    } else if (arg == "--mjcf" && a + 1 < argc) {
      mjcf_out = argv[++a];
    } else if ((arg == "--check" || arg == "--reps") && a + 1 < argc) {
      (arg == "--check" ? check : reps) = std::atoi(argv[++a]);
    } else {
      paths.push_back(argv[a]);
    }
  }
  if (paths.size() != 2 || check < 1 || reps < 1) {
    die("usage: bench [--strict] [--check K] [--reps R] [--mjcf OUT.xml] MODEL.bin STATES.bin");
  }

  // inputs and the three models
  static sd_model model;
  load_model(paths[0], &model);
  States s = load_states(paths[1], model.ndof);
  Libraries lib(&model);
  int n = s.ndof;
  if (mjcf_out) {
    std::ofstream(mjcf_out) << mjcf_text(&model);
  }

  // agreement on the first states
  bool ok = true;
  std::string agreement = check_agreement(lib, s, std::min(check, s.n), &ok);

  // timing: each pass evaluates every state once; steps restart from the stored state
  std::vector<double> out(n), q_work(n), qd_work(n);
  auto row = [&](const std::vector<double>& v, int i) { return &v[size_t(i) * n]; };
  auto restart = [&](int i) {
    std::copy(row(s.q, i), row(s.q, i) + n, q_work.begin());
    std::copy(row(s.qd, i), row(s.qd, i) + n, qd_work.begin());
  };
  std::vector<Contest> contests = {
      {"rnea",
       {{"sd_rnea", [&](int i, double* sink) {
           lib.sd_inverse(row(s.q, i), row(s.qd, i), row(s.qdd, i), out.data());
           *sink += out[0];
         }},
        {"pin_rnea", [&](int i, double* sink) {
           *sink += lib.pin_inverse(row(s.q, i), row(s.qd, i), row(s.qdd, i))[0];
         }},
        {"mj_inverse", [&](int i, double* sink) {
           *sink += lib.mj_inv(row(s.q, i), row(s.qd, i), row(s.qdd, i))[0];
         }}}},
      {"forward",
       {{"sd_forward", [&](int i, double* sink) {
           lib.sd_direct(row(s.q, i), row(s.qd, i), row(s.tau, i), out.data());
           *sink += out[0];
         }},
        {"pin_aba", [&](int i, double* sink) {
           *sink += lib.pin_direct(row(s.q, i), row(s.qd, i), row(s.tau, i))[0];
         }},
        {"mj_forward", [&](int i, double* sink) {
           *sink += lib.mj_fwd(row(s.q, i), row(s.qd, i), row(s.tau, i))[0];
         }}}},
      {"rk4",
       {{"sd_rk4", [&](int i, double* sink) {
           restart(i);
           lib.sd_rk4(q_work.data(), qd_work.data(), row(s.tau, i));
           *sink += q_work[0] + qd_work[0];
         }},
        {"pin_rk4", [&](int i, double* sink) {
           restart(i);
           lib.pin_rk4(q_work.data(), qd_work.data(), row(s.tau, i));
           *sink += q_work[0] + qd_work[0];
         }},
        {"mj_step_rk4", [&](int i, double* sink) {
           lib.mj_rk4(row(s.q, i), row(s.qd, i), row(s.tau, i));
           *sink += lib.mj_d->qpos[0] + lib.mj_d->qvel[0];
         }}}},
  };
  time_interleaved(reps, s.n, contests);

  // servodyn counts bad numbers instead of failing; report any
  for (int w = 0; w < SD_NWARNING; w++) {
    if (lib.sd_d->warning[w]) {
      std::fprintf(stderr, "bench: warning: servodyn warning counter %d = %d\n", w,
                   lib.sd_d->warning[w]);
    }
  }

  std::printf("{\"ndof\":%d,\"nbody\":%d,\"nstates\":%d,\"reps\":%d,\"agreement\":%s,%s}\n", n,
              model.nbody, s.n, reps, agreement.c_str(), timing_json(contests).c_str());
  return strict && !ok ? 3 : 0;
}
