// _core_control.c: the binding's Controller (the closed-form controller step, and a closed loop
// run in C against a plant) and Trajectory (C2 keyframe interpolation) types. See _core.h.
#include "_core.h"

#include <math.h>
#include <string.h>

//---------------------------------- Controller ---------------------------------------------------

typedef struct {
  PyObject_HEAD
  CoreObject* core;              // the controller's model and scratch data
  sd_control_config config;
  sd_control_state state;
} ControllerObject;

static int Controller_init(ControllerObject* self, PyObject* args, PyObject* kwargs) {
  static char* kwlist[] = {"core", "mode", "update_ticks", "kp", "kd", "tau_max", "friction_coulomb",
                           "friction_viscous", "friction_speed", NULL};
  PyObject *core, *kp, *kd, *tau_max, *coulomb = NULL, *viscous = NULL;
  int mode, update_ticks;
  double speed = 0.0;
  if (!PyArg_ParseTupleAndKeywords(args, kwargs, "O!iiOOO|OOd", kwlist, &CoreType, &core, &mode,
                                   &update_ticks, &kp, &kd, &tau_max, &coulomb, &viscous, &speed)) {
    return -1;
  }
  Py_INCREF(core);
  Py_XSETREF(self->core, (CoreObject*)core);
  sd_control_config* c = &self->config;
  memset(c, 0, sizeof(*c));
  c->mode = mode;
  c->update_ticks = update_ticks;
  int nv = self->core->model.ndof;
  if (sd_fill(c->kp, kp, nv, "kp") || sd_fill(c->kd, kd, nv, "kd") ||
      sd_fill(c->tau_max, tau_max, nv, "tau_max") ||
      (coulomb && coulomb != Py_None && sd_fill(c->friction_coulomb, coulomb, nv, "friction_coulomb")) ||
      (viscous && viscous != Py_None && sd_fill(c->friction_viscous, viscous, nv, "friction_viscous"))) {
    return -1;
  }
  c->friction_speed = (sd_real)speed;
  int err = sd_control_check(&self->core->model, c);
  if (err != SD_CONTROL_OK) {
    PyErr_Format(PyExc_ValueError, "controller: %s", sd_control_strerror(err));
    return -1;
  }
  sd_control_reset(&self->state);
  return 0;
}

static void Controller_dealloc(ControllerObject* self) {
  Py_XDECREF(self->core);
  Py_TYPE(self)->tp_free((PyObject*)self);
}

static PyObject* Controller_reset(ControllerObject* self, PyObject* Py_UNUSED(ignored)) {
  sd_control_reset(&self->state);
  Py_RETURN_NONE;
}

// step(q_d, qd_d, qdd_d, q, qd) -> tau: one small step of the controller
static PyObject* Controller_step(ControllerObject* self, PyObject* args) {
  PyObject *oqd_, *oqdd_, *oqdd_d, *oq, *oqv;
  if (!PyArg_ParseTuple(args, "OOOOO", &oqd_, &oqdd_, &oqdd_d, &oq, &oqv)) {
    return NULL;
  }
  const sd_model* m = &self->core->model;
  sd_real q_d[SD_MAX_Q], qd_d[SD_MAX_DOF], qdd_d[SD_MAX_DOF], q[SD_MAX_Q], qd[SD_MAX_DOF];
  sd_real tau[SD_MAX_DOF];
  if (sd_load_vector(q_d, oqd_, m->nq, "q_d") || sd_load_vector(qd_d, oqdd_, m->ndof, "qd_d") ||
      sd_load_vector(qdd_d, oqdd_d, m->ndof, "qdd_d") || sd_load_vector(q, oq, m->nq, "q") ||
      sd_load_vector(qd, oqv, m->ndof, "qd")) {
    return NULL;
  }
  sd_control_step(m, &self->core->data, &self->config, &self->state, q_d, qd_d, qdd_d, q, qd, tau);
  if (self->state.status & SD_STATUS_OVERFLOW) {
    // the core zeroed every torque and counted a fault: a zero is not an answer
    PyErr_Format(PyExc_FloatingPointError,
                 "controller: finite inputs gave a non-finite torque at tick %ld (an overflow)",
                 self->state.tick - 1);
    return NULL;
  }
  npy_intp dims[1] = {m->ndof};
  PyArrayObject* out = (PyArrayObject*)PyArray_SimpleNew(1, dims, NPY_DOUBLE);
  if (out) {
    sd_store_row(PyArray_DATA(out), tau, m->ndof);
  }
  return (PyObject*)out;
}

// simulate(plant, q_d, qd_d, qdd_d, q0, qd0, dt, integrator) -> (q, qd, tau, ticks): the closed
// loop in C, one controller step and one plant step per row of the desired (N x ...) arrays.
// Row k of q, qd is the state the controller saw at tick k, row k of tau what it commanded. A
// plant state that turns non-finite, or a controller fault (its zero torque is the row's last),
// stops the run: ticks is then the number of rows filled.
static PyObject* Controller_simulate(ControllerObject* self, PyObject* args) {
  PyObject *oplant, *oq_d, *oqd_d, *oqdd_d, *oq0, *oqd0;
  double dt;
  int integrator;
  if (!PyArg_ParseTuple(args, "O!OOOOOdi", &CoreType, &oplant, &oq_d, &oqd_d, &oqdd_d, &oq0,
                        &oqd0, &dt, &integrator)) {
    return NULL;
  }
  CoreObject* plant = (CoreObject*)oplant;
  const sd_model* m = &self->core->model;
  const sd_model* pm = &plant->model;
  if (pm->nq != m->nq || pm->ndof != m->ndof) {
    PyErr_SetString(PyExc_ValueError, "the plant and the controller's model differ in size");
    return NULL;
  }
  if (!(dt > 0) || !isfinite(dt) || (integrator != SD_RK4 && integrator != SD_EULER)) {
    PyErr_SetString(PyExc_ValueError, "dt must be positive and the integrator rk4 or euler");
    return NULL;
  }
  int nq = m->nq, nv = m->ndof;
  sd_real q[SD_MAX_Q], qd[SD_MAX_DOF], tau[SD_MAX_DOF];
  if (sd_load_vector(q, oq0, nq, "q0") || sd_load_vector(qd, oqd0, nv, "qd0")) {
    return NULL;
  }
  npy_intp qtail[1] = {nq}, vtail[1] = {nv}, n1, n2, n3;
  int b1, b2, b3;
  PyArrayObject *aq = NULL, *aqd = NULL, *aqdd = NULL, *hq = NULL, *hqd = NULL, *htau = NULL;
  PyObject* result = NULL;
  aq = sd_as_rows(oq_d, "q_d", qtail, 1, &n1, &b1);
  if (aq) aqd = sd_as_rows(oqd_d, "qd_d", vtail, 1, &n2, &b2);
  if (aqd) aqdd = sd_as_rows(oqdd_d, "qdd_d", vtail, 1, &n3, &b3);
  if (!aqdd) goto done;
  if (!b1 || !b2 || !b3 || n1 != n2 || n1 != n3) {
    PyErr_SetString(PyExc_ValueError, "q_d, qd_d, qdd_d must be (N, ...) arrays of one length N");
    goto done;
  }
  {
    npy_intp dq[2] = {n1, nq}, dv[2] = {n1, nv};
    hq = (PyArrayObject*)PyArray_ZEROS(2, dq, NPY_DOUBLE, 0);
    hqd = (PyArrayObject*)PyArray_ZEROS(2, dv, NPY_DOUBLE, 0);
    htau = (PyArrayObject*)PyArray_ZEROS(2, dv, NPY_DOUBLE, 0);
    if (!hq || !hqd || !htau) goto done;
    const double* q_d = PyArray_DATA(aq);
    const double* qd_d = PyArray_DATA(aqd);
    const double* qdd_d = PyArray_DATA(aqdd);
    sd_real rq_d[SD_MAX_Q], rqd_d[SD_MAX_DOF], rqdd_d[SD_MAX_DOF];
    npy_intp k;
    int finite = 1;
    for (k = 0; k < n1 && finite; k++) {
      sd_load_row(rq_d, q_d + k * nq, nq);
      sd_load_row(rqd_d, qd_d + k * nv, nv);
      sd_load_row(rqdd_d, qdd_d + k * nv, nv);
      sd_control_step(m, &self->core->data, &self->config, &self->state, rq_d, rqd_d, rqdd_d, q,
                      qd, tau);
      finite &= !(self->state.status & (SD_STATUS_NONFINITE | SD_STATUS_OVERFLOW));  // a fault stops
      sd_store_row((double*)PyArray_DATA(hq) + k * nq, q, nq);
      sd_store_row((double*)PyArray_DATA(hqd) + k * nv, qd, nv);
      sd_store_row((double*)PyArray_DATA(htau) + k * nv, tau, nv);
      sd_step(pm, &plant->data, q, qd, tau, NULL, (sd_real)dt, integrator);
      for (int j = 0; j < nq; j++) {
        finite &= isfinite((double)q[j]) && (j >= nv || isfinite((double)qd[j]));
      }
    }
    result = Py_BuildValue("(OOOn)", hq, hqd, htau, (Py_ssize_t)k);
  }
done:
  Py_XDECREF(aq);
  Py_XDECREF(aqd);
  Py_XDECREF(aqdd);
  Py_XDECREF(hq);
  Py_XDECREF(hqd);
  Py_XDECREF(htau);
  return result;
}

// set_gains(kp, kd, error_lowpass=None): new PD gains (and the low-pass of the errors they act
// on; None keeps it) from the next step on (gain scheduling), checked like __init__'s
static PyObject* Controller_set_gains(ControllerObject* self, PyObject* args) {
  PyObject *okp, *okd, *olp = Py_None;
  if (!PyArg_ParseTuple(args, "OO|O", &okp, &okd, &olp)) {
    return NULL;
  }
  sd_control_config c = self->config;
  int nv = self->core->model.ndof;
  if (sd_fill(c.kp, okp, nv, "kp") || sd_fill(c.kd, okd, nv, "kd") ||
      (olp != Py_None && sd_fill(c.error_lowpass, olp, nv, "error_lowpass"))) {
    return NULL;
  }
  int err = sd_control_check(&self->core->model, &c);
  if (err != SD_CONTROL_OK) {
    PyErr_Format(PyExc_ValueError, "controller: %s", sd_control_strerror(err));
    return NULL;
  }
  self->config = c;
  Py_RETURN_NONE;
}

static PyObject* Controller_get(ControllerObject* self, void* closure) {
  switch ((int)(intptr_t)closure) {
    case 0: return PyLong_FromLong(self->state.tick);
    case 1: return PyLong_FromLong(self->state.status);
    case 2: return PyLong_FromLong(self->state.nlimited);
    default: return PyLong_FromLong(self->state.nfault);
  }
}

static PyMethodDef Controller_methods[] = {
    {"reset", (PyCFunction)Controller_reset, METH_NOARGS, "start a new run at tick 0"},
    {"set_gains", (PyCFunction)Controller_set_gains, METH_VARARGS,
     "set_gains(kp, kd, error_lowpass=None): new PD gains (and the errors' low-pass) from the next step on"},
    {"step", (PyCFunction)Controller_step, METH_VARARGS,
     "step(q_d, qd_d, qdd_d, q, qd) -> tau: one small_time_step of the controller"},
    {"simulate", (PyCFunction)Controller_simulate, METH_VARARGS,
     "simulate(plant, q_d, qd_d, qdd_d, q0, qd0, dt, integrator) -> (q, qd, tau, ticks)"},
    {NULL, NULL, 0, NULL},
};

static PyGetSetDef Controller_getset[] = {
    {"tick", (getter)Controller_get, NULL, "small steps since reset", (void*)0},
    {"status", (getter)Controller_get, NULL, "status bits of the last step (1 limited, 2 non-finite input, 4 overflow)",
     (void*)1},
    {"nlimited", (getter)Controller_get, NULL, "steps with a clamped torque", (void*)2},
    {"nfault", (getter)Controller_get, NULL, "steps refused: non-finite input or result", (void*)3},
    {NULL, NULL, NULL, NULL, NULL},
};

static PyTypeObject ControllerType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "servodyn." SD_STR(SD_MODULE_NAME) ".Controller",
    .tp_basicsize = sizeof(ControllerObject),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "The closed-form controller step of the C core, with its configuration and state.",
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Controller_init,
    .tp_dealloc = (destructor)Controller_dealloc,
    .tp_methods = Controller_methods,
    .tp_getset = Controller_getset,
};

//---------------------------------- Trajectory ---------------------------------------------------

typedef struct {
  PyObject_HEAD
  sd_trajectory trajectory;
} TrajectoryObject;

static int Trajectory_init(TrajectoryObject* self, PyObject* args, PyObject* kwargs) {
  static char* kwlist[] = {"t", "q", NULL};
  PyObject *ot, *oq;
  if (!PyArg_ParseTupleAndKeywords(args, kwargs, "OO", kwlist, &ot, &oq)) {
    return -1;
  }
  PyArrayObject* at = (PyArrayObject*)PyArray_FROMANY(ot, NPY_DOUBLE, 1, 1, NPY_ARRAY_CARRAY_RO);
  PyArrayObject* aq = at ? (PyArrayObject*)PyArray_FROMANY(oq, NPY_DOUBLE, 2, 2, NPY_ARRAY_CARRAY_RO)
                         : NULL;
  int ok = at && aq;
  sd_trajectory* tr = &self->trajectory;
  memset(tr, 0, sizeof(*tr));
  if (ok) {
    npy_intp nknot = PyArray_DIM(at, 0), ndof = PyArray_DIM(aq, 1);
    if (PyArray_DIM(aq, 0) != nknot || nknot < 2 || nknot > SD_MAX_KNOT || ndof < 1 ||
        ndof > SD_MAX_DOF) {
      PyErr_Format(PyExc_ValueError,
                   "keyframes: t (K,) and q (K, ndof) with 2 <= K <= %d and 1 <= ndof <= %d",
                   SD_MAX_KNOT, SD_MAX_DOF);
      ok = 0;
    } else {
      tr->nknot = (int)nknot;
      tr->ndof = (int)ndof;
      sd_load_row(tr->knot_t, PyArray_DATA(at), tr->nknot);
      for (int k = 0; k < tr->nknot; k++) {
        sd_load_row(tr->knot_q[k], (const double*)PyArray_DATA(aq) + k * ndof, tr->ndof);
      }
      int bad_knot = -1, bad_dof = -1;
      int err = sd_trajectory_setup(tr, &bad_knot, &bad_dof);
      if (err) {
        PyErr_Format(PyExc_ValueError, "keyframe %d, dof %d: %s", bad_knot, bad_dof,
                     sd_trajectory_strerror(err));
        ok = 0;
      }
    }
  }
  Py_XDECREF(at);
  Py_XDECREF(aq);
  return ok ? 0 : -1;
}

// eval(t) -> (q, qd, qdd), each (ndof,) for a scalar t or (N, ndof) for an array of times
static PyObject* Trajectory_eval(TrajectoryObject* self, PyObject* args) {
  PyObject* ot;
  if (!PyArg_ParseTuple(args, "O", &ot)) {
    return NULL;
  }
  PyArrayObject* at = (PyArrayObject*)PyArray_FROMANY(ot, NPY_DOUBLE, 0, 1, NPY_ARRAY_CARRAY_RO);
  if (!at) {
    return NULL;
  }
  const sd_trajectory* tr = &self->trajectory;
  int scalar = PyArray_NDIM(at) == 0;
  npy_intp n = scalar ? 1 : PyArray_DIM(at, 0);
  npy_intp dims[2] = {n, tr->ndof};
  int nd = scalar ? 1 : 2;
  npy_intp* shape = scalar ? dims + 1 : dims;
  PyArrayObject* out[3] = {NULL, NULL, NULL};
  PyObject* result = NULL;
  for (int k = 0; k < 3; k++) {
    out[k] = (PyArrayObject*)PyArray_SimpleNew(nd, shape, NPY_DOUBLE);
    if (!out[k]) goto done;
  }
  {
    const double* t = PyArray_DATA(at);
    sd_real q[SD_MAX_DOF], qd[SD_MAX_DOF], qdd[SD_MAX_DOF];
    for (npy_intp i = 0; i < n; i++) {
      sd_trajectory_eval(tr, (sd_real)t[i], q, qd, qdd);
      sd_store_row((double*)PyArray_DATA(out[0]) + i * tr->ndof, q, tr->ndof);
      sd_store_row((double*)PyArray_DATA(out[1]) + i * tr->ndof, qd, tr->ndof);
      sd_store_row((double*)PyArray_DATA(out[2]) + i * tr->ndof, qdd, tr->ndof);
    }
  }
  result = PyTuple_Pack(3, out[0], out[1], out[2]);
done:
  Py_DECREF(at);
  for (int k = 0; k < 3; k++) {
    Py_XDECREF(out[k]);
  }
  return result;
}

static PyObject* Trajectory_get(TrajectoryObject* self, void* closure) {
  const sd_trajectory* tr = &self->trajectory;
  if (closure) {
    return PyFloat_FromDouble((double)(tr->knot_t[tr->nknot - 1] - tr->knot_t[0]));
  }
  return PyLong_FromLong(tr->ndof);
}

static PyMethodDef Trajectory_methods[] = {
    {"eval", (PyCFunction)Trajectory_eval, METH_VARARGS,
     "eval(t) -> (q, qd, qdd) at a time or an array of times"},
    {NULL, NULL, 0, NULL},
};

static PyGetSetDef Trajectory_getset[] = {
    {"ndof", (getter)Trajectory_get, NULL, "dofs per keyframe", NULL},
    {"duration", (getter)Trajectory_get, NULL, "last keyframe time minus first", (void*)1},
    {NULL, NULL, NULL, NULL, NULL},
};

static PyTypeObject TrajectoryType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "servodyn." SD_STR(SD_MODULE_NAME) ".Trajectory",
    .tp_basicsize = sizeof(TrajectoryObject),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "Keyframes interpolated with C2 continuity by the C core.",
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Trajectory_init,
    .tp_methods = Trajectory_methods,
    .tp_getset = Trajectory_getset,
};

int sd_add_control_types(PyObject* module) {
  if (PyType_Ready(&ControllerType) < 0 || PyType_Ready(&TrajectoryType) < 0) {
    return -1;
  }
  Py_INCREF(&ControllerType);
  Py_INCREF(&TrajectoryType);
  if (PyModule_AddObject(module, "Controller", (PyObject*)&ControllerType) < 0 ||
      PyModule_AddObject(module, "Trajectory", (PyObject*)&TrajectoryType) < 0) {
    return -1;
  }
  PyModule_AddIntConstant(module, "MODE_FEEDFORWARD", SD_MODE_FEEDFORWARD);
  PyModule_AddIntConstant(module, "MODE_FEEDFORWARD_PD", SD_MODE_FEEDFORWARD_PD);
  PyModule_AddIntConstant(module, "MODE_COMPUTED_TORQUE", SD_MODE_COMPUTED_TORQUE);
  PyModule_AddIntConstant(module, "MODE_PD", SD_MODE_PD);
  PyModule_AddIntConstant(module, "MAX_KNOT", SD_MAX_KNOT);
  return 0;
}
