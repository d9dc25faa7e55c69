// _core.c: the CPython binding of the servodyn C core: the Core type (a model and its data:
// inverse and direct dynamics, integration) and the module itself. See _core.h.
#define SD_BINDING_MAIN
#include "_core.h"

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

//---------------------------------- array helpers ------------------------------------------------

PyArrayObject* sd_as_rows(PyObject* obj, const char* name, const npy_intp* tail, int ntail,
                          npy_intp* nrow, int* batched) {
  PyArrayObject* arr = (PyArrayObject*)PyArray_FROMANY(
      obj, NPY_DOUBLE, 0, 0, NPY_ARRAY_C_CONTIGUOUS | NPY_ARRAY_ALIGNED | NPY_ARRAY_FORCECAST);
  if (!arr) {
    return NULL;
  }
  int nd = PyArray_NDIM(arr);
  int ok = (nd == ntail || nd == ntail + 1);
  for (int k = 0; ok && k < ntail; k++) {
    ok = PyArray_DIM(arr, nd - ntail + k) == tail[k];
  }
  if (!ok) {
    char got[96] = "";
    int len = 0;
    for (int k = 0; k < nd && k < 4 && len < 80; k++) {
      len += snprintf(got + len, sizeof(got) - (size_t)len, k ? ", %ld" : "%ld",
                      (long)PyArray_DIM(arr, k));
    }
    PyErr_Format(PyExc_ValueError, "%s must have shape (%ld%s) or (N, %ld%s), got (%s%s)", name,
                 (long)tail[0], ntail == 2 ? ", 6" : ",", (long)tail[0], ntail == 2 ? ", 6" : "",
                 got, nd == 1 ? "," : "");
    Py_DECREF(arr);
    return NULL;
  }
  *batched = (nd == ntail + 1);
  *nrow = *batched ? PyArray_DIM(arr, 0) : 1;
  // every number must be finite: a NaN never reaches the core from here
  const double* x = (const double*)PyArray_DATA(arr);
  npy_intp total = PyArray_SIZE(arr);
  for (npy_intp k = 0; k < total; k++) {
    if (!isfinite(x[k])) {
      npy_intp width = total / (*nrow > 0 ? *nrow : 1);
      PyErr_Format(PyExc_ValueError, "%s has a non-finite value (row %ld, column %ld)", name,
                   (long)(width ? k / width : 0), (long)(width ? k % width : 0));
      Py_DECREF(arr);
      return NULL;
    }
  }
  return arr;
}

void sd_load_row(sd_real* dst, const double* src, int n) {
  for (int k = 0; k < n; k++) {
    dst[k] = (sd_real)src[k];
  }
}

int sd_allfinite_row(const sd_real* x, npy_intp n) {
  for (npy_intp k = 0; k < n; k++) {
    if (!isfinite((double)x[k])) {
      return 0;
    }
  }
  return 1;
}

void sd_store_row(double* dst, const sd_real* src, int n) {
  for (int k = 0; k < n; k++) {
    dst[k] = (double)src[k];
  }
}

// copy a float64 array of exactly `count` numbers into dst
int sd_fill(sd_real* dst, PyObject* obj, npy_intp count, const char* name) {
  PyArrayObject* arr = (PyArrayObject*)PyArray_FROMANY(
      obj, NPY_DOUBLE, 0, 0, NPY_ARRAY_C_CONTIGUOUS | NPY_ARRAY_ALIGNED | NPY_ARRAY_FORCECAST);
  if (!arr) {
    return -1;
  }
  if (PyArray_SIZE(arr) != count) {
    PyErr_Format(PyExc_ValueError, "%s must hold %ld numbers, got %ld", name, (long)count,
                 (long)PyArray_SIZE(arr));
    Py_DECREF(arr);
    return -1;
  }
  sd_load_row(dst, (const double*)PyArray_DATA(arr), (int)count);
  Py_DECREF(arr);
  return 0;
}

// load one state row of length n from a float64 array into dst, checking its size
int sd_load_vector(sd_real* dst, PyObject* obj, int n, const char* name) {
  npy_intp tail[1] = {n}, nrow;
  int batched;
  PyArrayObject* arr = sd_as_rows(obj, name, tail, 1, &nrow, &batched);
  if (!arr) {
    return -1;
  }
  if (batched) {
    PyErr_Format(PyExc_ValueError, "%s must be one state of %d numbers", name, n);
    Py_DECREF(arr);
    return -1;
  }
  sd_load_row(dst, PyArray_DATA(arr), n);
  Py_DECREF(arr);
  return 0;
}

static int fill_int(int* dst, PyObject* obj, npy_intp count, const char* name) {
  PyArrayObject* arr = (PyArrayObject*)PyArray_FROMANY(
      obj, NPY_LONG, 0, 0, NPY_ARRAY_C_CONTIGUOUS | NPY_ARRAY_ALIGNED | NPY_ARRAY_FORCECAST);
  if (!arr) {
    return -1;
  }
  if (PyArray_SIZE(arr) != count) {
    PyErr_Format(PyExc_ValueError, "%s must hold %ld integers, got %ld", name, (long)count,
                 (long)PyArray_SIZE(arr));
    Py_DECREF(arr);
    return -1;
  }
  const long* src = (const long*)PyArray_DATA(arr);
  for (npy_intp k = 0; k < count; k++) {
    dst[k] = (int)src[k];
  }
  Py_DECREF(arr);
  return 0;
}

//---------------------------------- construction -------------------------------------------------

static int Core_init(CoreObject* self, PyObject* args, PyObject* kwargs) {
  static char* kwlist[] = {"parent", "dofnum", "pos", "rot", "dof_rot", "mass", "com",
                           "inertia", "gravity", "free_root", "ball", "armature", NULL};
  PyObject *parent, *dofnum, *pos, *rot, *dof_rot, *mass, *com, *inertia, *gravity;
  PyObject *ball = Py_None, *armature = Py_None;
  int free_root = 0;
  if (!PyArg_ParseTupleAndKeywords(args, kwargs, "OOOOOOOOO|pOO", kwlist, &parent, &dofnum, &pos,
                                   &rot, &dof_rot, &mass, &com, &inertia, &gravity, &free_root,
                                   &ball, &armature)) {
    return -1;
  }
  sd_model* m = &self->model;
  memset(m, 0, sizeof(*m));
  memset(&self->data, 0, sizeof(self->data));
  Py_ssize_t nbody = PyObject_Length(parent);
  if (nbody < 1 || nbody > SD_MAX_BODY) {
    PyErr_Format(PyExc_ValueError, "a model needs 1 to %d bodies, got %zd", SD_MAX_BODY, nbody);
    return -1;
  }
  m->nbody = (int)nbody;
  m->free_root = free_root;
  if (fill_int(m->body_parent, parent, nbody, "parent") ||
      fill_int(m->body_dofnum, dofnum, nbody, "dofnum") ||
      (ball != Py_None && fill_int(m->body_ball, ball, nbody, "ball"))) {
    return -1;
  }
  int ndof = 0;
  for (int i = 0; i < m->nbody; i++) {
    m->body_dofadr[i] = ndof;
    int free = free_root && i == 0;
    if (!free && (m->body_dofnum[i] < 0 || m->body_dofnum[i] > SD_MAX_JOINT_DOF)) {
      PyErr_Format(PyExc_ValueError, "body %d: a joint has 0 to 3 dofs, got %d", i,
                   m->body_dofnum[i]);
      return -1;
    }
    ndof += m->body_dofnum[i];
  }
  if (ndof > SD_MAX_DOF) {
    PyErr_Format(PyExc_ValueError, "the model has %d dofs, this build allows %d", ndof, SD_MAX_DOF);
    return -1;
  }
  m->ndof = ndof;
  if (sd_fill(&m->body_pos[0][0], pos, 3 * nbody, "pos") ||
      sd_fill(&m->body_rot[0][0], rot, 9 * nbody, "rot") ||
      sd_fill(&m->dof_rot[0][0], dof_rot, 9 * (npy_intp)ndof, "dof_rot") ||
      sd_fill(m->body_mass, mass, nbody, "mass") ||
      sd_fill(&m->body_com[0][0], com, 3 * nbody, "com") ||
      sd_fill(&m->body_inertia[0][0], inertia, 6 * nbody, "inertia") ||
      sd_fill(m->gravity, gravity, 3, "gravity") ||
      (armature != Py_None && sd_fill(m->dof_armature, armature, ndof, "armature"))) {
    return -1;
  }
  int bad = -1;
  int err = sd_model_setup(m, &bad);
  if (err != SD_OK) {
    PyErr_Format(PyExc_ValueError, "body %d: %s", bad, sd_strerror(err));
    return -1;
  }
  return 0;
}

//---------------------------------- algorithms ---------------------------------------------------

typedef void (*sd_dynamics_fn)(const sd_model*, sd_data*, const sd_real*, const sd_real*,
                               const sd_real*, const sd_real*, sd_real*);

// shared body of rnea and forward: three (N x ndof) inputs, optional f_ext, one output
static PyObject* run_dynamics(CoreObject* self, PyObject* args, sd_dynamics_fn fn,
                              const char* third) {
  PyObject *oq, *oqd, *ox, *ofext = Py_None;
  if (!PyArg_ParseTuple(args, "OOO|O", &oq, &oqd, &ox, &ofext)) {
    return NULL;
  }
  const sd_model* m = &self->model;
  npy_intp tail[2] = {m->ndof, 6}, qtail[1] = {m->nq}, ftail[2] = {m->nbody, 6};
  npy_intp nq, nqd, nx, nf = 0;
  int bq, bqd, bx, bf = 0;
  PyArrayObject *aq = NULL, *aqd = NULL, *ax = NULL, *af = NULL, *out = NULL;
  aq = sd_as_rows(oq, "q", qtail, 1, &nq, &bq);
  if (aq) aqd = sd_as_rows(oqd, "qd", tail, 1, &nqd, &bqd);
  if (aqd) ax = sd_as_rows(ox, third, tail, 1, &nx, &bx);
  if (ax && ofext != Py_None) af = sd_as_rows(ofext, "f_ext", ftail, 2, &nf, &bf);
  if (!ax || (ofext != Py_None && !af)) goto done;
  if (bqd != bq || bx != bq || (af && bf && !bq) || nqd != nq || nx != nq ||
      (af && bf && nf != nq)) {
    PyErr_SetString(PyExc_ValueError, "inputs must all be single states or batches of one length N");
    goto done;
  }
  out = (PyArrayObject*)PyArray_SimpleNew(PyArray_NDIM(aqd), PyArray_DIMS(aqd), NPY_DOUBLE);
  if (!out) goto done;
  {
    const double* q = PyArray_DATA(aq);
    const double* qd = PyArray_DATA(aqd);
    const double* x = PyArray_DATA(ax);
    const double* fe = af ? PyArray_DATA(af) : NULL;
    double* y = PyArray_DATA(out);
    int n = m->ndof, nqc = m->nq, nfe = 6 * m->nbody;
    sd_real rq[SD_MAX_Q], rqd[SD_MAX_DOF], rx[SD_MAX_DOF], ry[SD_MAX_DOF];
    sd_real rf[6 * SD_MAX_BODY];
    for (npy_intp r = 0; r < nq; r++) {
      sd_load_row(rq, q + r * nqc, nqc);
      sd_load_row(rqd, qd + r * n, n);
      sd_load_row(rx, x + r * n, n);
      if (fe) sd_load_row(rf, fe + (bf ? r * nfe : 0), nfe);
      // the core zeroes a non-finite result and counts it: here that is an error, never a 0
      int nonfinite = self->data.warning[SD_WARN_NONFINITE];
      fn(m, &self->data, rq, rqd, rx, fe ? rf : NULL, ry);
      if (self->data.warning[SD_WARN_NONFINITE] != nonfinite) {
        PyErr_Format(PyExc_FloatingPointError,
                     "%s: non-finite result at row %ld (the inputs overflow double precision)",
                     fn == sd_rnea ? "inverse dynamics" : "forward dynamics", (long)r);
        Py_CLEAR(out);
        goto done;
      }
      sd_store_row(y + r * n, ry, n);
    }
  }
done:
  Py_XDECREF(aq);
  Py_XDECREF(aqd);
  Py_XDECREF(ax);
  Py_XDECREF(af);
  return (PyObject*)out;
}

static PyObject* Core_rnea(CoreObject* self, PyObject* args) {
  return run_dynamics(self, args, sd_rnea, "qdd");
}

static PyObject* Core_forward(CoreObject* self, PyObject* args) {
  return run_dynamics(self, args, sd_forward, "tau");
}

// regressor(q, qd, qdd) -> Y: (ndof, 10 nbody) per state, (N, ndof, 10 nbody) for a batch
static PyObject* Core_regressor(CoreObject* self, PyObject* args) {
  PyObject *oq, *oqd, *oqdd;
  if (!PyArg_ParseTuple(args, "OOO", &oq, &oqd, &oqdd)) {
    return NULL;
  }
  const sd_model* m = &self->model;
  npy_intp tail[1] = {m->ndof}, qtail[1] = {m->nq};
  npy_intp nq, nqd, nqdd;
  int bq, bqd, bqdd;
  PyArrayObject *aq = NULL, *aqd = NULL, *aqdd = NULL, *out = NULL;
  sd_real* rY = NULL;
  aq = sd_as_rows(oq, "q", qtail, 1, &nq, &bq);
  if (aq) aqd = sd_as_rows(oqd, "qd", tail, 1, &nqd, &bqd);
  if (aqd) aqdd = sd_as_rows(oqdd, "qdd", tail, 1, &nqdd, &bqdd);
  if (!aqdd) goto done;
  if (bqd != bq || bqdd != bq || nqd != nq || nqdd != nq) {
    PyErr_SetString(PyExc_ValueError, "inputs must all be single states or batches of one length N");
    goto done;
  }
  {
    int n = m->ndof, nqc = m->nq, ncol = SD_NPARAM * m->nbody;
    npy_intp dims[3] = {nq, n, ncol};
    out = (PyArrayObject*)PyArray_SimpleNew(bq ? 3 : 2, bq ? dims : dims + 1, NPY_DOUBLE);
    rY = PyMem_Malloc(sizeof(sd_real) * (size_t)(n > 0 ? n : 1) * (size_t)ncol);
    if (!out || !rY) {
      if (!rY) PyErr_NoMemory();
      Py_CLEAR(out);
      goto done;
    }
    sd_real rq[SD_MAX_Q], rqd[SD_MAX_DOF], rqdd[SD_MAX_DOF];
    double* y = PyArray_DATA(out);
    for (npy_intp r = 0; r < nq; r++) {
      sd_load_row(rq, (const double*)PyArray_DATA(aq) + r * nqc, nqc);
      sd_load_row(rqd, (const double*)PyArray_DATA(aqd) + r * n, n);
      sd_load_row(rqdd, (const double*)PyArray_DATA(aqdd) + r * n, n);
      sd_regressor(m, &self->data, rq, rqd, rqdd, rY);
      // finite inputs can still overflow (qd^2 at 1e154): an error naming the row, never an inf
      if (!sd_allfinite_row(rY, n * ncol)) {
        PyErr_Format(PyExc_FloatingPointError,
                     "regressor: non-finite result at row %ld (the inputs overflow double precision)",
                     (long)r);
        Py_CLEAR(out);
        goto done;
      }
      sd_store_row(y + r * (npy_intp)n * ncol, rY, n * ncol);
    }
  }
done:
  PyMem_Free(rY);
  Py_XDECREF(aq);
  Py_XDECREF(aqd);
  Py_XDECREF(aqdd);
  return (PyObject*)out;
}

// momentum(q, qd) -> (p, g, ctqd): M(q) qd, g(q) and C(q, qd)' qd, one state or a batch
static PyObject* Core_momentum(CoreObject* self, PyObject* args) {
  PyObject *oq, *oqd;
  if (!PyArg_ParseTuple(args, "OO", &oq, &oqd)) {
    return NULL;
  }
  const sd_model* m = &self->model;
  npy_intp tail[1] = {m->ndof}, qtail[1] = {m->nq}, nq, nqd;
  int bq, bqd;
  PyArrayObject *aq = NULL, *aqd = NULL, *out[3] = {NULL, NULL, NULL};
  PyObject* result = NULL;
  aq = sd_as_rows(oq, "q", qtail, 1, &nq, &bq);
  if (aq) aqd = sd_as_rows(oqd, "qd", tail, 1, &nqd, &bqd);
  if (!aqd) goto done;
  if (bqd != bq || nqd != nq) {
    PyErr_SetString(PyExc_ValueError, "inputs must all be single states or batches of one length N");
    goto done;
  }
  for (int k = 0; k < 3; k++) {
    out[k] = (PyArrayObject*)PyArray_SimpleNew(PyArray_NDIM(aqd), PyArray_DIMS(aqd), NPY_DOUBLE);
    if (!out[k]) goto done;
  }
  {
    int n = m->ndof, nqc = m->nq;
    sd_real rq[SD_MAX_Q], rqd[SD_MAX_DOF], rp[SD_MAX_DOF], rg[SD_MAX_DOF], rc[SD_MAX_DOF];
    for (npy_intp r = 0; r < nq; r++) {
      sd_load_row(rq, (const double*)PyArray_DATA(aq) + r * nqc, nqc);
      sd_load_row(rqd, (const double*)PyArray_DATA(aqd) + r * n, n);
      sd_momentum(m, &self->data, rq, rqd, rp, rg, rc);
      if (!sd_allfinite_row(rp, n) || !sd_allfinite_row(rg, n) || !sd_allfinite_row(rc, n)) {
        PyErr_Format(PyExc_FloatingPointError,
                     "momentum: non-finite result at row %ld (the inputs overflow the precision)",
                     (long)r);
        goto done;
      }
      sd_store_row((double*)PyArray_DATA(out[0]) + r * n, rp, n);
      sd_store_row((double*)PyArray_DATA(out[1]) + r * n, rg, n);
      sd_store_row((double*)PyArray_DATA(out[2]) + r * n, rc, n);
    }
  }
  result = PyTuple_Pack(3, (PyObject*)out[0], (PyObject*)out[1], (PyObject*)out[2]);
done:
  Py_XDECREF(aq);
  Py_XDECREF(aqd);
  for (int k = 0; k < 3; k++) Py_XDECREF(out[k]);
  return result;
}

// step(q, qd, tau, dt, integrator, nsteps=1, f_ext=None) -> (q, qd): nsteps steps with tau held
static PyObject* Core_step(CoreObject* self, PyObject* args, PyObject* kwargs) {
  static char* kwlist[] = {"q", "qd", "tau", "dt", "integrator", "nsteps", "f_ext", NULL};
  PyObject *oq, *oqd, *otau, *ofext = Py_None;
  double dt;
  int integrator, nsteps = 1;
  if (!PyArg_ParseTupleAndKeywords(args, kwargs, "OOOdi|iO", kwlist, &oq, &oqd, &otau, &dt,
                                   &integrator, &nsteps, &ofext)) {
    return NULL;
  }
  if (!(dt > 0) || !isfinite(dt) || nsteps < 1) {
    PyErr_SetString(PyExc_ValueError, "dt must be positive and finite, nsteps at least 1");
    return NULL;
  }
  if (integrator != SD_RK4 && integrator != SD_EULER) {
    PyErr_SetString(PyExc_ValueError, "integrator must be rk4 or euler");
    return NULL;
  }
  const sd_model* m = &self->model;
  npy_intp tail[2] = {m->ndof, 6}, qtail[1] = {m->nq}, ftail[2] = {m->nbody, 6};
  npy_intp nq, nqd, nt, nf = 0;
  int bq, bqd, bt, bf = 0;
  PyArrayObject *aq = NULL, *aqd = NULL, *at = NULL, *af = NULL, *oq2 = NULL, *oqd2 = NULL;
  PyObject* result = NULL;
  aq = sd_as_rows(oq, "q", qtail, 1, &nq, &bq);
  if (aq) aqd = sd_as_rows(oqd, "qd", tail, 1, &nqd, &bqd);
  if (aqd) at = sd_as_rows(otau, "tau", tail, 1, &nt, &bt);
  if (at && ofext != Py_None) af = sd_as_rows(ofext, "f_ext", ftail, 2, &nf, &bf);
  if (!at || (ofext != Py_None && !af)) goto done;
  if (bqd != bq || bt != bq || (af && bf && !bq) || nqd != nq || nt != nq ||
      (af && bf && nf != nq)) {
    PyErr_SetString(PyExc_ValueError, "inputs must all be single states or batches of one length N");
    goto done;
  }
  oq2 = (PyArrayObject*)PyArray_SimpleNew(PyArray_NDIM(aq), PyArray_DIMS(aq), NPY_DOUBLE);
  oqd2 = (PyArrayObject*)PyArray_SimpleNew(PyArray_NDIM(aqd), PyArray_DIMS(aqd), NPY_DOUBLE);
  if (!oq2 || !oqd2) goto done;
  {
    int n = m->ndof, nqc = m->nq, nfe = 6 * m->nbody;
    const double* fe = af ? PyArray_DATA(af) : NULL;
    sd_real rq[SD_MAX_Q], rqd[SD_MAX_DOF], rt[SD_MAX_DOF], rf[6 * SD_MAX_BODY];
    for (npy_intp r = 0; r < nq; r++) {
      sd_load_row(rq, (const double*)PyArray_DATA(aq) + r * nqc, nqc);
      sd_load_row(rqd, (const double*)PyArray_DATA(aqd) + r * n, n);
      sd_load_row(rt, (const double*)PyArray_DATA(at) + r * n, n);
      if (fe) sd_load_row(rf, fe + (bf ? r * nfe : 0), nfe);
      for (int s = 0; s < nsteps; s++) {
        int nonfinite = self->data.warning[SD_WARN_NONFINITE];
        sd_step(m, &self->data, rq, rqd, rt, fe ? rf : NULL, (sd_real)dt, integrator);
        // a diverging integration is an error the caller must see, never a silent inf or NaN,
        // nor a step taken with an acceleration the core zeroed because it overflowed
        int diverged = self->data.warning[SD_WARN_NONFINITE] != nonfinite;
        for (int j = 0; j < nqc; j++) {
          if (diverged || !isfinite((double)rq[j]) || (j < n && !isfinite((double)rqd[j]))) {
            PyErr_Format(PyExc_FloatingPointError,
                         "the integration diverged: non-finite state after step %d of row %ld",
                         s + 1, (long)r);
            goto done;
          }
        }
      }
      sd_store_row((double*)PyArray_DATA(oq2) + r * nqc, rq, nqc);
      sd_store_row((double*)PyArray_DATA(oqd2) + r * n, rqd, n);
    }
  }
  result = PyTuple_Pack(2, (PyObject*)oq2, (PyObject*)oqd2);
done:
  Py_XDECREF(aq);
  Py_XDECREF(aqd);
  Py_XDECREF(at);
  Py_XDECREF(af);
  Py_XDECREF(oq2);
  Py_XDECREF(oqd2);
  return result;
}

// set_root_force(force, point): a force fixed in the base frame at a point of a free body 0
static PyObject* Core_set_root_force(CoreObject* self, PyObject* args) {
  PyObject *oforce, *opoint;
  if (!PyArg_ParseTuple(args, "OO", &oforce, &opoint)) {
    return NULL;
  }
  if (!self->model.free_root) {
    PyErr_SetString(PyExc_ValueError, "a root force needs a model whose body 0 floats free");
    return NULL;
  }
  sd_real force[3], point[3];
  if (sd_fill(force, oforce, 3, "force") || sd_fill(point, opoint, 3, "point")) {
    return NULL;
  }
  for (int k = 0; k < 3; k++) {
    if (!isfinite((double)force[k]) || !isfinite((double)point[k])) {
      PyErr_SetString(PyExc_ValueError, "the root force and its point must be finite");
      return NULL;
    }
    self->data.root_force[k] = force[k];
    self->data.root_point[k] = point[k];
  }
  Py_RETURN_NONE;
}

// the model struct's bytes, for tools that load the core without Python (the benchmark)
static PyObject* Core_model_bytes(CoreObject* self, PyObject* Py_UNUSED(ignored)) {
  return PyBytes_FromStringAndSize((const char*)&self->model, sizeof(sd_model));
}

static PyObject* Core_warnings(CoreObject* self, void* Py_UNUSED(closure)) {
  return Py_BuildValue("{s:i,s:i}", "nonfinite", self->data.warning[SD_WARN_NONFINITE],
                       "singular", self->data.warning[SD_WARN_SINGULAR]);
}

static PyObject* Core_get_gravity(CoreObject* self, void* Py_UNUSED(closure)) {
  const sd_real* g = self->model.gravity;
  return Py_BuildValue("(ddd)", (double)g[0], (double)g[1], (double)g[2]);
}

static int Core_set_gravity(CoreObject* self, PyObject* value, void* Py_UNUSED(closure)) {
  sd_real g[3];
  if (!value || sd_fill(g, value, 3, "gravity")) {
    if (!value) PyErr_SetString(PyExc_TypeError, "gravity cannot be deleted");
    return -1;
  }
  for (int k = 0; k < 3; k++) {
    if (!isfinite((double)g[k])) {
      PyErr_SetString(PyExc_ValueError, "gravity must be finite");
      return -1;
    }
  }
  memcpy(self->model.gravity, g, sizeof(g));
  return 0;
}

static PyObject* Core_get_int(CoreObject* self, void* closure) {
  const sd_model* m = &self->model;
  long which = (long)(intptr_t)closure;
  return PyLong_FromLong(which == 1 ? m->nbody : which == 2 ? m->nq : m->ndof);
}

static PyMethodDef Core_methods[] = {
    {"rnea", (PyCFunction)Core_rnea, METH_VARARGS,
     "rnea(q, qd, qdd, f_ext=None) -> tau: inverse dynamics, one state or a batch"},
    {"forward", (PyCFunction)Core_forward, METH_VARARGS,
     "forward(q, qd, tau, f_ext=None) -> qdd: direct dynamics, one state or a batch"},
    {"regressor", (PyCFunction)Core_regressor, METH_VARARGS,
     "regressor(q, qd, qdd) -> Y (ndof, 10 nbody): tau = Y pi, one state or a batch"},
    {"momentum", (PyCFunction)Core_momentum, METH_VARARGS,
     "momentum(q, qd) -> (p, g, ctqd): M(q) qd, g(q), C(q, qd)' qd; one state or a batch"},
    {"step", (PyCFunction)(void (*)(void))Core_step, METH_VARARGS | METH_KEYWORDS,
     "step(q, qd, tau, dt, integrator, nsteps=1, f_ext=None) -> (q, qd)"},
    {"model_bytes", (PyCFunction)Core_model_bytes, METH_NOARGS, "the sd_model struct as bytes"},
    {"set_root_force", (PyCFunction)Core_set_root_force, METH_VARARGS,
     "set_root_force(force, point): base-frame force at a point of the free body 0 (zero: none)"},
    {NULL, NULL, 0, NULL},
};

static PyGetSetDef Core_getset[] = {
    {"warnings", (getter)Core_warnings, NULL, "warning counters of the core", NULL},
    {"gravity", (getter)Core_get_gravity, (setter)Core_set_gravity, "gravity (m/s^2)", NULL},
    {"nbody", (getter)Core_get_int, NULL, "number of bodies", (void*)1},
    {"ndof", (getter)Core_get_int, NULL, "number of dofs (length of qd)", NULL},
    {"nq", (getter)Core_get_int, NULL, "length of q (one more with a free root)", (void*)2},
    {NULL, NULL, NULL, NULL, NULL},
};

PyTypeObject CoreType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "servodyn." SD_STR(SD_MODULE_NAME) ".Core",
    .tp_basicsize = sizeof(CoreObject),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "A validated model and its data, as the C core holds them.",
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Core_init,
    .tp_methods = Core_methods,
    .tp_getset = Core_getset,
};

// solid_inertia(kind, mass, dims) -> (com_z, (xx, yy, zz, xy, xz, yz)) about the com, axis along z
static PyObject* solid_inertia(PyObject* Py_UNUSED(module), PyObject* args) {
  const char* kind;
  double mass;
  PyObject* odims;
  if (!PyArg_ParseTuple(args, "sdO", &kind, &mass, &odims)) {
    return NULL;
  }
  sd_real dims[3] = {0, 0, 0}, inertia[6], com_z = 0;
  PyObject* seq = PySequence_Fast(odims, "dims must be a sequence of numbers");
  if (!seq) {
    return NULL;
  }
  Py_ssize_t nd = PySequence_Fast_GET_SIZE(seq);
  for (Py_ssize_t k = 0; k < nd && k < 3; k++) {
    dims[k] = (sd_real)PyFloat_AsDouble(PySequence_Fast_GET_ITEM(seq, k));
  }
  Py_DECREF(seq);
  if (PyErr_Occurred()) {
    return NULL;
  }
  int err;
  if (!strcmp(kind, "cylinder") && nd == 2) {          // radius, length
    err = sd_inertia_cylinder((sd_real)mass, dims[0], dims[1], inertia);
    com_z = dims[1] / 2;
  } else if (!strcmp(kind, "sphere") && nd == 1) {     // radius
    err = sd_inertia_sphere((sd_real)mass, dims[0], inertia);
  } else if (!strcmp(kind, "ellipsoid") && nd == 3) {  // semi-axes a, b, c
    err = sd_inertia_ellipsoid((sd_real)mass, dims[0], dims[1], dims[2], inertia);
  } else if (!strcmp(kind, "frustum") && nd == 3) {    // r0, r1, length
    err = sd_inertia_frustum((sd_real)mass, dims[0], dims[1], dims[2], &com_z, inertia);
  } else {
    PyErr_Format(PyExc_ValueError, "unknown solid '%s' with %zd dimensions", kind, nd);
    return NULL;
  }
  if (err) {
    PyErr_Format(PyExc_ValueError, "%s: mass and dimensions must be positive", kind);
    return NULL;
  }
  return Py_BuildValue("d(dddddd)", (double)com_z, (double)inertia[0], (double)inertia[1],
                       (double)inertia[2], (double)inertia[3], (double)inertia[4],
                       (double)inertia[5]);
}

static PyMethodDef module_methods[] = {
    {"solid_inertia", solid_inertia, METH_VARARGS,
     "solid_inertia(kind, mass, dims) -> (com_z, inertia6): cylinder (r, L), sphere (r,), "
     "ellipsoid (a, b, c), frustum (r0, r1, L)"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef core_module = {
    PyModuleDef_HEAD_INIT, SD_STR(SD_MODULE_NAME), "The servodyn C dynamics core.", -1,
    module_methods,
};

PyMODINIT_FUNC SD_CAT(PyInit_, SD_MODULE_NAME)(void) {
  import_array();
  if (PyType_Ready(&CoreType) < 0) {
    return NULL;
  }
  PyObject* mod = PyModule_Create(&core_module);
  if (!mod) {
    return NULL;
  }
  Py_INCREF(&CoreType);
  PyModule_AddObject(mod, "Core", (PyObject*)&CoreType);
  if (sd_add_control_types(mod) < 0 || sd_add_observer_type(mod) < 0) {
    Py_DECREF(mod);
    return NULL;
  }
  PyModule_AddIntConstant(mod, "RK4", SD_RK4);
  PyModule_AddIntConstant(mod, "EULER", SD_EULER);
  PyModule_AddIntConstant(mod, "MAX_BODY", SD_MAX_BODY);
  PyModule_AddIntConstant(mod, "MAX_DOF", SD_MAX_DOF);
  PyModule_AddIntConstant(mod, "REAL_BYTES", (int)sizeof(sd_real));
  PyModule_AddIntConstant(mod, "NPARAM", SD_NPARAM);
  return mod;
}
