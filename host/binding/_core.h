// _core.h: what the files of the servodyn CPython binding share.
//
// The binding is built twice by setup.py: servodyn._core with sd_real = double and
// servodyn._core32 with sd_real = float (-DSD_SINGLE), so the MCU's arithmetic can be checked
// from Python. Arrays in and out are float64; a leading batch axis is looped over in C.
#ifndef SD_BINDING_H
#define SD_BINDING_H

#define PY_SSIZE_T_CLEAN
#define NPY_NO_DEPRECATED_API NPY_1_7_API_VERSION
#ifndef SD_MODULE_NAME
#define SD_MODULE_NAME _core
#endif
#define SD_STR2(x) #x
#define SD_STR(x) SD_STR2(x)
#define SD_CAT2(a, b) a##b
#define SD_CAT(a, b) SD_CAT2(a, b)
#define PY_ARRAY_UNIQUE_SYMBOL SD_CAT(servodyn_numpy_api, SD_MODULE_NAME)
#ifndef SD_BINDING_MAIN
#define NO_IMPORT_ARRAY
#endif
#include <Python.h>
#include <numpy/arrayobject.h>

#include "servodyn.h"

// a validated model and its data, as the C core holds them
typedef struct {
  PyObject_HEAD
  sd_model model;
  sd_data data;
} CoreObject;

extern PyTypeObject CoreType;

// A float64 C-contiguous, all-finite view of obj whose trailing shape is `tail` (ntail dims),
// with an optional leading batch axis; *nrow gets the batch size, *batched whether it had one.
PyArrayObject* sd_as_rows(PyObject* obj, const char* name, const npy_intp* tail, int ntail,
                          npy_intp* nrow, int* batched);

// Copy n numbers between float64 and sd_real.
void sd_load_row(sd_real* dst, const double* src, int n);
void sd_store_row(double* dst, const sd_real* src, int n);

// 1 when all n numbers are finite.
int sd_allfinite_row(const sd_real* x, npy_intp n);

// Copy a float64 array of exactly `count` numbers into dst; -1 with a Python error otherwise.
int sd_fill(sd_real* dst, PyObject* obj, npy_intp count, const char* name);

// Load one state of exactly n numbers (no batch axis) from a float64 array; -1 with an error.
int sd_load_vector(sd_real* dst, PyObject* obj, int n, const char* name);

// Add the Observer type to the module (_core_observer.c); -1 on failure.
int sd_add_observer_type(PyObject* module);

// Add the Controller and Trajectory types to the module; -1 on failure.
int sd_add_control_types(PyObject* module);

#endif  // SD_BINDING_H
