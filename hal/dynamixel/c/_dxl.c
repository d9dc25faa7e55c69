// _dxl.c: the firmware's Dynamixel codec (hal/dynamixel/c/dxl.c) for the host, as servodyn._dxl.
//
// The host's tick and the simulated bus use it where the Python codec costs per byte: the CRC-16
// and the reading of a status packet, including the fast sync read reply and its running CRCs.
//
//   crc16(data, crc=0) -> int
//   r = Reader(); r.reset(); r.feed(data) -> (status, used)   status: 0 more, 1 packet, < 0 bad
//   r.id, r.instruction, r.error, r.params
//   r.fast_split(size, ids) -> (good, errors, data): blocks of a fast read reply of `size` bytes
//     each from `ids` (bytes) in order; good = how many are whole and correct (len(ids): all),
//     errors = each good block's ERR byte, data = their data bytes one after another.
//   fast_reply_seal(frame, sizes) -> bytes sealed: the running CRCs of a fast read reply laid
//     out in the writable buffer frame, block k holding sizes[k] data bytes (the servos' side)
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include "dxl.h"

static PyObject* py_crc16(PyObject* self, PyObject* args) {
  (void)self;
  Py_buffer data;
  unsigned int crc = 0;
  if (!PyArg_ParseTuple(args, "y*|I", &data, &crc)) return NULL;
  uint16_t out = dxl_crc((uint16_t)crc, (const uint8_t*)data.buf, (size_t)data.len);
  PyBuffer_Release(&data);
  return PyLong_FromLong(out);
}

typedef struct {
  PyObject_HEAD
  dxl_reader reader;
  int last;        // the last feed's status
} ReaderObject;

static int Reader_init(ReaderObject* self, PyObject* args, PyObject* kwds) {
  (void)args;
  (void)kwds;
  dxl_reader_reset(&self->reader);
  self->last = DXL_MORE;
  return 0;
}

static PyObject* Reader_reset(ReaderObject* self, PyObject* unused) {
  (void)unused;
  dxl_reader_reset(&self->reader);
  self->last = DXL_MORE;
  Py_RETURN_NONE;
}

static PyObject* Reader_feed(ReaderObject* self, PyObject* args) {
  Py_buffer data;
  if (!PyArg_ParseTuple(args, "y*", &data)) return NULL;
  size_t used = 0;
  self->last = dxl_reader_feed_bytes(&self->reader, (const uint8_t*)data.buf, (size_t)data.len, &used);
  PyBuffer_Release(&data);
  return Py_BuildValue("in", self->last, (Py_ssize_t)used);
}

static PyObject* Reader_fast_split(ReaderObject* self, PyObject* args) {
  unsigned int size;
  Py_buffer ids;
  if (!PyArg_ParseTuple(args, "Iy*", &size, &ids)) return NULL;
  enum { MAX_BLOCKS = 64 };
  if (ids.len > MAX_BLOCKS || size > DXL_MAX_PARAM) {
    PyBuffer_Release(&ids);
    PyErr_SetString(PyExc_ValueError, "fast_split: at most 64 servos and 256 bytes each");
    return NULL;
  }
  dxl_block blocks[MAX_BLOCKS];
  int good = self->last == DXL_PACKET ? dxl_fast_reply_split(&self->reader, (uint16_t)size, (const uint8_t*)ids.buf,
                                                             (size_t)ids.len, blocks)
                                      : 0;
  PyBuffer_Release(&ids);
  if (good < 0) good = 0;
  PyObject* errors = PyBytes_FromStringAndSize(NULL, good);
  PyObject* data = PyBytes_FromStringAndSize(NULL, (Py_ssize_t)good * size);
  if (!errors || !data) {
    Py_XDECREF(errors);
    Py_XDECREF(data);
    return NULL;
  }
  char* e = PyBytes_AS_STRING(errors);
  char* d = PyBytes_AS_STRING(data);
  for (int k = 0; k < good; k++) {
    e[k] = (char)blocks[k].error;
    memcpy(d + (size_t)k * size, blocks[k].data, size);
  }
  return Py_BuildValue("iNN", good, errors, data);
}

static PyObject* Reader_get(ReaderObject* self, void* which) {
  switch ((int)(intptr_t)which) {
    case 0: return PyLong_FromLong(self->reader.id);
    case 1: return PyLong_FromLong(self->reader.instruction);
    case 2: return PyLong_FromLong(self->reader.error);
    default:
      return PyBytes_FromStringAndSize((const char*)self->reader.param, self->reader.nparam);
  }
}

static PyMethodDef Reader_methods[] = {
    {"reset", (PyCFunction)Reader_reset, METH_NOARGS, "forget a half-read frame"},
    {"feed", (PyCFunction)Reader_feed, METH_VARARGS,
     "feed(data) -> (status, used): stops at the first complete or bad frame"},
    {"fast_split", (PyCFunction)Reader_fast_split, METH_VARARGS,
     "fast_split(size, ids) -> (good, errors, data) of the fast read reply just read"},
    {NULL, NULL, 0, NULL},
};

static PyGetSetDef Reader_getset[] = {
    {"id", (getter)Reader_get, NULL, "the packet's ID", (void*)0},
    {"instruction", (getter)Reader_get, NULL, "the packet's instruction", (void*)1},
    {"error", (getter)Reader_get, NULL, "a status packet's ERR byte", (void*)2},
    {"params", (getter)Reader_get, NULL, "the parameters after ERR, destuffed", (void*)3},
    {NULL, NULL, NULL, NULL, NULL},
};

static PyTypeObject ReaderType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "servodyn.hal.dynamixel._dxl.Reader",
    .tp_basicsize = sizeof(ReaderObject),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "The firmware's Protocol 2.0 packet reader (hal/dynamixel/c/dxl.c).",
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Reader_init,
    .tp_methods = Reader_methods,
    .tp_getset = Reader_getset,
};

static PyObject* py_fast_reply_seal(PyObject* self, PyObject* args) {
  (void)self;
  Py_buffer frame;
  PyObject* sizes;
  if (!PyArg_ParseTuple(args, "w*O", &frame, &sizes)) return NULL;
  enum { MAX_BLOCKS = 256 };
  uint16_t size[MAX_BLOCKS];
  PyObject* seq = PySequence_Fast(sizes, "fast_reply_seal: sizes must be a sequence of ints");
  Py_ssize_t count = seq ? PySequence_Fast_GET_SIZE(seq) : 0;
  if (seq && count > MAX_BLOCKS) {
    PyErr_SetString(PyExc_ValueError, "fast_reply_seal: at most 256 blocks");
  }
  for (Py_ssize_t k = 0; seq && !PyErr_Occurred() && k < count; k++) {
    long value = PyLong_AsLong(PySequence_Fast_GET_ITEM(seq, k));
    if (value < 0 || value > 0xFFFF) {
      if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "fast_reply_seal: a block size is 0..65535");
    } else {
      size[k] = (uint16_t)value;
    }
  }
  size_t sealed = 0;
  if (seq && !PyErr_Occurred()) {
    sealed = dxl_fast_reply_seal((uint8_t*)frame.buf, (size_t)frame.len, size, (size_t)count);
    if (!sealed) PyErr_SetString(PyExc_ValueError, "fast_reply_seal: the blocks do not fit the frame");
  }
  Py_XDECREF(seq);
  PyBuffer_Release(&frame);
  if (PyErr_Occurred()) return NULL;
  return PyLong_FromSize_t(sealed);
}

static PyMethodDef module_methods[] = {
    {"crc16", py_crc16, METH_VARARGS, "crc16(data, crc=0) -> the Protocol 2.0 CRC-16, continuing from crc"},
    {"fast_reply_seal", py_fast_reply_seal, METH_VARARGS,
     "fast_reply_seal(frame, sizes) -> bytes sealed: each block's running CRC written in place"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef dxl_module = {
    PyModuleDef_HEAD_INIT, "_dxl", "The Dynamixel codec of the firmware, for the host.", -1, module_methods,
};

PyMODINIT_FUNC PyInit__dxl(void) {
  if (PyType_Ready(&ReaderType) < 0) return NULL;
  PyObject* mod = PyModule_Create(&dxl_module);
  if (!mod) return NULL;
  Py_INCREF(&ReaderType);
  if (PyModule_AddObject(mod, "Reader", (PyObject*)&ReaderType) < 0) {
    Py_DECREF(&ReaderType);
    Py_DECREF(mod);
    return NULL;
  }
  PyModule_AddIntConstant(mod, "MORE", DXL_MORE);
  PyModule_AddIntConstant(mod, "PACKET", DXL_PACKET);
  PyModule_AddIntConstant(mod, "BAD_CRC", DXL_BAD_CRC);
  return mod;
}
