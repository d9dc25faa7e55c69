// _core_observer.c: the binding's Observer type, the C core's generalized-momentum observer
// (sd_observer.h) on a Core's model, one sample at a time or over recorded arrays. See _core.h.
#include "_core.h"

#include <math.h>
#include <string.h>

typedef struct {
  PyObject_HEAD
  CoreObject* core;              // the observer's model and scratch data
  sd_observer_config config;
  sd_observer_state state;
} ObserverObject;

// Observer(core, dt, gain, friction_coulomb=None, friction_viscous=None, friction_speed=0,
//          lowpass=None)
static int Observer_init(ObserverObject* self, PyObject* args, PyObject* kwargs) {
  static char* kwlist[] = {"core", "dt", "gain", "friction_coulomb", "friction_viscous",
                           "friction_speed", "lowpass", NULL};
  PyObject *core, *gain, *coulomb = Py_None, *viscous = Py_None, *lowpass = Py_None;
  double dt, speed = 0.0;
  if (!PyArg_ParseTupleAndKeywords(args, kwargs, "O!dO|OOdO", kwlist, &CoreType, &core, &dt,
                                   &gain, &coulomb, &viscous, &speed, &lowpass)) {
    return -1;
  }
  Py_INCREF(core);
  Py_XSETREF(self->core, (CoreObject*)core);
  sd_observer_config* c = &self->config;
  memset(c, 0, sizeof(*c));
  memset(&self->state, 0, sizeof(self->state));
  int nv = self->core->model.ndof;
  c->dt = (sd_real)dt;
  c->friction_speed = (sd_real)speed;
  if (sd_fill(c->gain, gain, nv, "gain") ||
      (coulomb != Py_None && sd_fill(c->friction_coulomb, coulomb, nv, "friction_coulomb")) ||
      (viscous != Py_None && sd_fill(c->friction_viscous, viscous, nv, "friction_viscous")) ||
      (lowpass != Py_None && sd_fill(c->lowpass, lowpass, nv, "lowpass"))) {
    return -1;
  }
  int err = sd_observer_check(&self->core->model, c);
  if (err != SD_OBSERVER_OK) {
    PyErr_Format(PyExc_ValueError, "observer: %s", sd_observer_strerror(err));
    return -1;
  }
  // not started: a step before reset() starts at its own sample
  self->state.tick = -1;
  return 0;
}

static void Observer_dealloc(ObserverObject* self) {
  Py_XDECREF(self->core);
  Py_TYPE(self)->tp_free((PyObject*)self);
}

static PyObject* residual_array(const ObserverObject* self) {
  npy_intp dims[1] = {self->core->model.ndof};
  PyArrayObject* out = (PyArrayObject*)PyArray_SimpleNew(1, dims, NPY_DOUBLE);
  if (out) {
    sd_store_row(PyArray_DATA(out), self->state.rf, (int)dims[0]);
  }
  return (PyObject*)out;
}

// reset(q, qd): start at the measured state, r = 0
static PyObject* Observer_reset(ObserverObject* self, PyObject* args) {
  PyObject *oq, *oqd;
  if (!PyArg_ParseTuple(args, "OO", &oq, &oqd)) {
    return NULL;
  }
  const sd_model* m = &self->core->model;
  sd_real q[SD_MAX_Q], qd[SD_MAX_DOF];
  if (sd_load_vector(q, oq, m->nq, "q") || sd_load_vector(qd, oqd, m->ndof, "qd")) {
    return NULL;
  }
  sd_observer_reset(m, &self->core->data, &self->config, &self->state, q, qd);
  Py_RETURN_NONE;
}

// step(q, qd, tau_m) -> r: one sample
static PyObject* Observer_step(ObserverObject* self, PyObject* args) {
  PyObject *oq, *oqd, *otau;
  if (!PyArg_ParseTuple(args, "OOO", &oq, &oqd, &otau)) {
    return NULL;
  }
  const sd_model* m = &self->core->model;
  sd_real q[SD_MAX_Q], qd[SD_MAX_DOF], tau[SD_MAX_DOF];
  if (sd_load_vector(q, oq, m->nq, "q") || sd_load_vector(qd, oqd, m->ndof, "qd") ||
      sd_load_vector(tau, otau, m->ndof, "tau_m")) {
    return NULL;
  }
  sd_observer_step(m, &self->core->data, &self->config, &self->state, q, qd, tau);
  if (self->state.status & SD_OBSERVER_NONFINITE) {
    PyErr_Format(PyExc_FloatingPointError,
                 "observer: finite inputs gave a non-finite momentum at sample %ld (an overflow)",
                 self->state.tick);
    return NULL;
  }
  return residual_array(self);
}

// run(q, qd, tau_m) -> r (N x ndof): reset at row 0, then a step at every further row (row 0's
// residual is 0); the arrays are (N x nq), (N x ndof), (N x ndof)
static PyObject* Observer_run(ObserverObject* self, PyObject* args) {
  PyObject *oq, *oqd, *otau;
  if (!PyArg_ParseTuple(args, "OOO", &oq, &oqd, &otau)) {
    return NULL;
  }
  const sd_model* m = &self->core->model;
  sd_data* d = &self->core->data;
  npy_intp qtail[1] = {m->nq}, vtail[1] = {m->ndof}, n1, n2, n3;
  int b1, b2, b3;
  PyArrayObject *aq = NULL, *aqd = NULL, *at = NULL, *out = NULL;
  aq = sd_as_rows(oq, "q", qtail, 1, &n1, &b1);
  if (aq) aqd = sd_as_rows(oqd, "qd", vtail, 1, &n2, &b2);
  if (aqd) at = sd_as_rows(otau, "tau_m", vtail, 1, &n3, &b3);
  if (!at) goto done;
  if (!b1 || !b2 || !b3 || n1 != n2 || n1 != n3 || n1 < 1) {
    PyErr_SetString(PyExc_ValueError, "q, qd and tau_m must be (N, ...) arrays of one length N >= 1");
    goto done;
  }
  npy_intp dims[2] = {n1, m->ndof};
  out = (PyArrayObject*)PyArray_SimpleNew(2, dims, NPY_DOUBLE);
  if (!out) goto done;
  {
    int nq = m->nq, nv = m->ndof;
    sd_real q[SD_MAX_Q], qd[SD_MAX_DOF], tau[SD_MAX_DOF];
    double* r = PyArray_DATA(out);
    for (npy_intp k = 0; k < n1; k++) {
      sd_load_row(q, (const double*)PyArray_DATA(aq) + k * nq, nq);
      sd_load_row(qd, (const double*)PyArray_DATA(aqd) + k * nv, nv);
      sd_load_row(tau, (const double*)PyArray_DATA(at) + k * nv, nv);
      if (k == 0) {
        sd_observer_reset(m, d, &self->config, &self->state, q, qd);
      } else {
        sd_observer_step(m, d, &self->config, &self->state, q, qd, tau);
      }
      if (self->state.status & SD_OBSERVER_NONFINITE) {
        PyErr_Format(PyExc_FloatingPointError,
                     "observer: finite inputs gave a non-finite momentum at row %ld (an overflow)",
                     (long)k);
        Py_CLEAR(out);
        goto done;
      }
      sd_store_row(r + k * nv, self->state.rf, nv);
    }
  }
done:
  Py_XDECREF(aq);
  Py_XDECREF(aqd);
  Py_XDECREF(at);
  return (PyObject*)out;
}

static PyObject* Observer_residual(ObserverObject* self, void* Py_UNUSED(closure)) {
  return residual_array(self);
}

static PyObject* Observer_tick(ObserverObject* self, void* Py_UNUSED(closure)) {
  return PyLong_FromLong(self->state.tick);
}

static PyMethodDef Observer_methods[] = {
    {"reset", (PyCFunction)Observer_reset, METH_VARARGS, "reset(q, qd): start at the state, r = 0"},
    {"step", (PyCFunction)Observer_step, METH_VARARGS,
     "step(q, qd, tau_m) -> r: one sample; tau_m acted over the period ending now"},
    {"run", (PyCFunction)Observer_run, METH_VARARGS,
     "run(q, qd, tau_m) -> r (N, ndof): reset at row 0, a step at each further row"},
    {NULL, NULL, 0, NULL},
};

static PyGetSetDef Observer_getset[] = {
    {"residual", (getter)Observer_residual, NULL,
     "the residual (N m) of the last sample, after the low-pass", NULL},
    {"tick", (getter)Observer_tick, NULL, "samples since reset (-1: not started)", NULL},
    {NULL, NULL, NULL, NULL, NULL},
};

static PyTypeObject ObserverType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "servodyn." SD_STR(SD_MODULE_NAME) ".Observer",
    .tp_basicsize = sizeof(ObserverObject),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "Observer(core, dt, gain, friction_coulomb=None, friction_viscous=None, "
              "friction_speed=0, lowpass=None): the generalized-momentum observer of the C core; its "
              "residual is r after the low-pass (rf).",
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Observer_init,
    .tp_dealloc = (destructor)Observer_dealloc,
    .tp_methods = Observer_methods,
    .tp_getset = Observer_getset,
};

int sd_add_observer_type(PyObject* module) {
  if (PyType_Ready(&ObserverType) < 0) {
    return -1;
  }
  Py_INCREF(&ObserverType);
  if (PyModule_AddObject(module, "Observer", (PyObject*)&ObserverType) < 0) {
    return -1;
  }
  return 0;
}
