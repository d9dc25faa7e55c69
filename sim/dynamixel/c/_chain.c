// _chain.c: the simulated servos' per-tick work over a whole chain, in C
// (servodyn.sim.dynamixel._chain, used by sim/dynamixel/chain.py).
//
// Each function here is one of Servo's (sim/dynamixel/servo.py) for every servo of a chain at
// once, the same operations in the same order on the same doubles, so the registers and the
// currents are bit for bit the Python ones (tests/test_sim_chain.py compares them over randomized
// states). It works on the servos' own control tables (bytearrays) and attributes; whatever is
// not its case (another mode, a value the Python code would refuse with an exception, a tripping
// watchdog) it leaves to the servo's Python method. The layout (which field is where) and every
// constant come from Python (the control table, the servo models): nothing is written twice.
//
//   Chain(servos, fields, constants, units)
//     servos: the Servo objects; fields: one (address, size, signed) per name of FIELDS, in that
//     order; constants: per servo (stall_current, nominal_voltage, no_load_speed, current_unit);
//     units: (ticks_per_rev, velocity_unit, pwm_full, watchdog_unit, current_mode).
//   chain.currents(position, velocity, out, start) -> k                Servo.output_current
//     position, velocity: doubles (buffers) at each horn; out: a writable buffer of doubles.
//     Servos start, start + 1, ... in turn, up to the first one left to Python (k; n when none):
//     their currents in `out`, their Present PWM written (torque off: 0, and their PID's
//     reset() called). Called again from k + 1, the servos change in the order Python's would.
//   chain.torques(current, velocity, out, start, Mechanics, fields) -> k   Servo.output_torque
//     As currents: from start up to the first servo left to Python (k).
//   chain.publish(position, velocity, current)                        Servo.set_present
//   chain.refresh() -> general                                        Servo._refresh_present
//     The Present registers of every stale servo; a mask of those left to Python.
//   chain.clock(now) -> general                                       DynamixelWire.tick / Servo.clock
//   chain.heard(now) -> general                                       Servo.heard, every servo
//     The servos whose watchdog trips now are left to Python (general).
//   chain.write(params, rule) -> written, or -1                       DynamixelWire._writes (SYNC WRITE)
//   chain.fast_read(ids, address, length, frame, starts, alert_bit, access_error) -> n, -1, -2
//                                                                     DynamixelWire._fast_reads
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define MAX_SERVOS 62     // a mask of them is a positive int64

enum {
  F_TORQUE_ENABLE, F_DRIVE_MODE, F_OPERATING_MODE, F_PRESENT_INPUT_VOLTAGE, F_GOAL_PWM, F_PWM_LIMIT,
  F_GOAL_CURRENT, F_CURRENT_LIMIT, F_PRESENT_PWM, F_HOMING_OFFSET, F_PRESENT_POSITION, F_PRESENT_VELOCITY,
  F_PRESENT_CURRENT, F_MOVING, F_MOVING_THRESHOLD, F_REALTIME_TICK, F_BUS_WATCHDOG, F_ID, F_SECONDARY_ID,
  F_STATUS_RETURN_LEVEL, F_HARDWARE_ERROR_STATUS, N_FIELDS
};
static const char* FIELD_NAMES[N_FIELDS] = {
  "torque_enable", "drive_mode", "operating_mode", "present_input_voltage", "goal_pwm", "pwm_limit",
  "goal_current", "current_limit", "present_pwm", "homing_offset", "present_position", "present_velocity",
  "present_current", "moving", "moving_threshold", "realtime_tick", "bus_watchdog", "id", "secondary_id",
  "status_return_level", "hardware_error_status",
};

typedef struct {
  int address, size, is_signed;
} Field;

typedef struct {
  double stall_current, nominal_voltage, no_load_speed, current_unit;
} Constants;

typedef struct {
  PyObject_HEAD
  int n;
  PyObject* servos[MAX_SERVOS];
  PyObject* tables[MAX_SERVOS];      // each servo's _table (a bytearray of fixed size)
  Constants constants[MAX_SERVOS];
  Field fields[N_FIELDS];
  long long ticks_per_rev;
  double velocity_unit, pwm_full, watchdog_unit;
  long current_mode;
  Py_ssize_t need;                   // bytes a table needs to hold every field
} Chain;

// the Servo attributes read and written, interned once
static PyObject *s_stale, *s_shaft, *s_turns, *s_zero_ticks, *s_clocked_at, *s_heard_at, *s_silent, *s_pid, *s_reset,
    *s_mechanics;

static inline long long get(const uint8_t* t, Field f) {
  const uint8_t* p = t + f.address;
  switch (f.size) {
    case 1: return f.is_signed ? (long long)(int8_t)p[0] : (long long)p[0];
    case 2: {
      uint16_t v = (uint16_t)(p[0] | (p[1] << 8));
      return f.is_signed ? (long long)(int16_t)v : (long long)v;
    }
    default: {
      uint32_t v = (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
      return f.is_signed ? (long long)(int32_t)v : (long long)v;
    }
  }
}

static inline void put(uint8_t* t, Field f, long long value) {
  uint8_t* p = t + f.address;
  for (int k = 0; k < f.size; k++) p[k] = (uint8_t)(((unsigned long long)value >> (8 * k)) & 0xFF);
}

// Python's max(-bound, min(bound - 1, round(x))) for the field's bound 2**(8 size - 1); 0 where
// round() raises (x not finite)
static inline int clamped(double x, Field f, long long* out) {
  if (!isfinite(x)) return 0;
  double r = nearbyint(x);                     // round half to even, as round()
  long long bound = 1LL << (8 * f.size - 1);
  if (r > (double)(bound - 1)) *out = bound - 1;
  else if (r < (double)-bound) *out = -bound;
  else *out = (long long)r;
  return 1;
}

// min(a, b) and max(a, b) as Python's: the first unless the second is strictly smaller / larger
static inline double pmin(double a, double b) { return b < a ? b : a; }
static inline double pmax(double a, double b) { return b > a ? b : a; }
static inline long long lmin(long long a, long long b) { return b < a ? b : a; }
static inline long long lmax(long long a, long long b) { return b > a ? b : a; }

static inline uint8_t* table_of(Chain* self, int k) { return (uint8_t*)PyByteArray_AS_STRING(self->tables[k]); }

// whether every servo's table still holds every field (a bytearray could be cut short): if not,
// every call leaves everything to Python
static inline int whole(Chain* self) {
  for (int k = 0; k < self->n; k++)
    if (PyByteArray_GET_SIZE(self->tables[k]) < self->need) return 0;
  return 1;
}

static void Chain_dealloc(Chain* self) {
  for (int k = 0; k < self->n; k++) {
    Py_XDECREF(self->servos[k]);
    Py_XDECREF(self->tables[k]);
  }
  Py_TYPE(self)->tp_free((PyObject*)self);
}

static int Chain_init(Chain* self, PyObject* args, PyObject* kwds) {
  (void)kwds;
  PyObject *servos, *fields, *constants;
  if (!PyArg_ParseTuple(args, "OOO(Ldddl)", &servos, &fields, &constants, &self->ticks_per_rev,
                        &self->velocity_unit, &self->pwm_full, &self->watchdog_unit, &self->current_mode))
    return -1;
  servos = PySequence_Fast(servos, "servos: a sequence");
  if (!servos) return -1;
  Py_ssize_t n = PySequence_Fast_GET_SIZE(servos);
  if (n > MAX_SERVOS || !PyTuple_Check(fields) || PyTuple_GET_SIZE(fields) != N_FIELDS ||
      !PyTuple_Check(constants) || PyTuple_GET_SIZE(constants) != n) {
    Py_DECREF(servos);
    PyErr_Format(PyExc_ValueError, "Chain: at most %d servos, %d fields and one constants tuple a servo",
                 MAX_SERVOS, N_FIELDS);
    return -1;
  }
  self->need = 0;
  for (int f = 0; f < N_FIELDS; f++) {
    Field* field = &self->fields[f];
    if (!PyArg_ParseTuple(PyTuple_GET_ITEM(fields, f), "iip", &field->address, &field->size, &field->is_signed)) {
      Py_DECREF(servos);
      return -1;
    }
    if (field->size != 1 && field->size != 2 && field->size != 4) {
      Py_DECREF(servos);
      PyErr_Format(PyExc_ValueError, "Chain: field %s of %d bytes", FIELD_NAMES[f], field->size);
      return -1;
    }
    if (field->address + field->size > self->need) self->need = field->address + field->size;
  }
  for (int k = 0; k < self->n; k++) {       // a second __init__ starts afresh
    Py_CLEAR(self->servos[k]);
    Py_CLEAR(self->tables[k]);
  }
  self->n = 0;
  for (Py_ssize_t k = 0; k < n; k++) {
    PyObject* servo = PySequence_Fast_GET_ITEM(servos, k);
    Constants* c = &self->constants[k];
    if (!PyArg_ParseTuple(PyTuple_GET_ITEM(constants, k), "dddd", &c->stall_current, &c->nominal_voltage,
                          &c->no_load_speed, &c->current_unit)) {
      Py_DECREF(servos);
      return -1;
    }
    PyObject* table = PyObject_GetAttrString(servo, "_table");
    if (!table) {
      Py_DECREF(servos);
      return -1;
    }
    Py_ssize_t size = PyByteArray_Check(table) ? PyByteArray_GET_SIZE(table) : 0;
    int big_enough = 1;
    for (int f = 0; f < N_FIELDS; f++) big_enough &= self->fields[f].address + self->fields[f].size <= size;
    if (!PyByteArray_Check(table) || !big_enough) {
      Py_DECREF(table);
      Py_DECREF(servos);
      PyErr_SetString(PyExc_ValueError, "Chain: a servo's _table is not a bytearray holding every field");
      return -1;
    }
    Py_INCREF(servo);
    self->servos[k] = servo;
    self->tables[k] = table;
    self->n = (int)k + 1;
  }
  Py_DECREF(servos);
  return 0;
}

// a buffer of n doubles, C-contiguous
static int doubles(PyObject* obj, Py_buffer* view, int n, int writable) {
  if (PyObject_GetBuffer(obj, view, (writable ? PyBUF_WRITABLE : 0) | PyBUF_FORMAT | PyBUF_C_CONTIGUOUS) < 0)
    return 0;
  if (view->itemsize != sizeof(double) || !view->format || strcmp(view->format, "d") != 0 ||
      view->len != (Py_ssize_t)(n * sizeof(double))) {
    PyBuffer_Release(view);
    PyErr_Format(PyExc_ValueError, "Chain: expected %d doubles", n);
    return 0;
  }
  return 1;
}

// three buffers of n doubles, the third writable when `out` (each released on failure)
static int three(Chain* self, PyObject* a, PyObject* b, PyObject* c, Py_buffer view[3], int out) {
  PyObject* objs[3] = {a, b, c};
  for (int i = 0; i < 3; i++) {
    if (!doubles(objs[i], &view[i], self->n, out && i == 2)) {
      for (int j = 0; j < i; j++) PyBuffer_Release(&view[j]);
      return 0;
    }
  }
  return 1;
}

static void release(Py_buffer view[3]) {
  for (int i = 0; i < 3; i++) PyBuffer_Release(&view[i]);
}

// Servo.output_current, torque on in Current Control Mode (and torque off)
static PyObject* Chain_currents(Chain* self, PyObject* args) {
  PyObject *p_obj, *v_obj, *o_obj;
  int start;
  if (!PyArg_ParseTuple(args, "OOOi", &p_obj, &v_obj, &o_obj, &start)) return NULL;
  Py_buffer view[3];
  if (!three(self, p_obj, v_obj, o_obj, view, 1)) return NULL;
  const double* velocity = (const double*)view[1].buf;
  double* out = (double*)view[2].buf;
  const Field* F = self->fields;
  int k = start < 0 ? 0 : start;
  for (; k < self->n && whole(self); k++) {
    uint8_t* t = table_of(self, k);
    const Constants* c = &self->constants[k];
    if (get(t, F[F_TORQUE_ENABLE]) != 1) {          // torque off: the PID reset, no PWM, no current
      PyObject* pid = PyObject_GetAttr(self->servos[k], s_pid);
      PyObject* done = pid ? PyObject_CallMethodNoArgs(pid, s_reset) : NULL;
      Py_XDECREF(pid);
      if (!done) {
        release(view);
        return NULL;
      }
      Py_DECREF(done);
      put(t, F[F_PRESENT_PWM], 0);
      out[k] = 0.0;
      continue;
    }
    long long input_voltage = get(t, F[F_PRESENT_INPUT_VOLTAGE]);
    if (get(t, F[F_OPERATING_MODE]) != self->current_mode || c->no_load_speed == 0.0 || c->stall_current == 0.0 ||
        c->nominal_voltage == 0.0 || input_voltage == 0)
      break;
    double sign = (get(t, F[F_DRIVE_MODE]) & 0x01) ? -1.0 : 1.0;
    double back_emf = sign * velocity[k] / c->no_load_speed;
    double supply = (double)input_voltage / 10.0 / c->nominal_voltage;
    long long goal_pwm = get(t, F[F_GOAL_PWM]);
    long long pwm_cap = lmin(goal_pwm < 0 ? -goal_pwm : goal_pwm, get(t, F[F_PWM_LIMIT]));
    long long limit = get(t, F[F_CURRENT_LIMIT]);
    long long units = lmax(-limit, lmin(limit, get(t, F[F_GOAL_CURRENT])));
    double stall = c->stall_current;
    double reach = stall * (double)pwm_cap / self->pwm_full * supply;
    double amps = pmax(-reach - stall * back_emf, pmin(reach - stall * back_emf, (double)units * c->current_unit));
    double pwm = (amps / stall + back_emf) / supply * self->pwm_full;
    long long present_pwm;
    if (!clamped(pwm, F[F_PRESENT_PWM], &present_pwm)) break;
    put(t, F[F_PRESENT_PWM], present_pwm);
    out[k] = sign * amps;
  }
  release(view);
  return PyLong_FromLong(k);
}

// Servo.set_present for every servo
static PyObject* Chain_publish(Chain* self, PyObject* args) {
  PyObject *p_obj, *v_obj, *c_obj;
  if (!PyArg_ParseTuple(args, "OOO", &p_obj, &v_obj, &c_obj)) return NULL;
  Py_buffer b[3];
  if (!three(self, p_obj, v_obj, c_obj, b, 0)) return NULL;
  int ok = 1;
  for (int k = 0; k < self->n && ok; k++) {
    PyObject* shaft = Py_BuildValue("(ddd)", ((double*)b[0].buf)[k], ((double*)b[1].buf)[k], ((double*)b[2].buf)[k]);
    ok = shaft && PyObject_SetAttr(self->servos[k], s_shaft, shaft) == 0 &&
         PyObject_SetAttr(self->servos[k], s_stale, Py_True) == 0;
    Py_XDECREF(shaft);
  }
  release(b);
  if (!ok) return NULL;
  Py_RETURN_NONE;
}

// Servo._refresh_present of servo k from its shaft; 0 where Python would raise (left to it), -1 on error
static int present(Chain* self, int k) {
  PyObject* servo = self->servos[k];
  PyObject* shaft = PyObject_GetAttr(servo, s_shaft);
  if (!shaft) return -1;
  double position, velocity, current;
  int parsed = PyTuple_Check(shaft) && PyTuple_GET_SIZE(shaft) == 3 &&
               PyFloat_CheckExact(PyTuple_GET_ITEM(shaft, 0)) && PyFloat_CheckExact(PyTuple_GET_ITEM(shaft, 1)) &&
               PyFloat_CheckExact(PyTuple_GET_ITEM(shaft, 2));
  if (parsed) {
    position = PyFloat_AS_DOUBLE(PyTuple_GET_ITEM(shaft, 0));
    velocity = PyFloat_AS_DOUBLE(PyTuple_GET_ITEM(shaft, 1));
    current = PyFloat_AS_DOUBLE(PyTuple_GET_ITEM(shaft, 2));
  }
  Py_DECREF(shaft);
  if (!parsed) return 0;                        // not three floats: Python's arithmetic decides
  PyObject* turns_obj = PyObject_GetAttr(servo, s_turns);
  if (!turns_obj) return -1;
  PyObject* zero_obj = PyObject_GetAttr(servo, s_zero_ticks);
  if (!zero_obj) {
    Py_DECREF(turns_obj);
    return -1;
  }
  int overflow_turns = 0, overflow_zero = 0;
  long long turns = PyLong_Check(turns_obj) ? PyLong_AsLongLongAndOverflow(turns_obj, &overflow_turns) : 0;
  long long zero = PyLong_Check(zero_obj) ? PyLong_AsLongLongAndOverflow(zero_obj, &overflow_zero) : 0;
  int exact = PyLong_CheckExact(turns_obj) && PyLong_CheckExact(zero_obj) && !overflow_turns && !overflow_zero &&
              llabs(turns) < (1LL << 30) && llabs(zero) < (1LL << 52);
  Py_DECREF(turns_obj);
  Py_DECREF(zero_obj);
  if (!exact) return 0;                         // ints beyond a double's exact range: Python's
  const Field* F = self->fields;
  uint8_t* t = table_of(self, k);
  const Constants* c = &self->constants[k];
  double sign = (get(t, F[F_DRIVE_MODE]) & 0x01) ? -1.0 : 1.0;
  double tpr = (double)self->ticks_per_rev;
  double ticks = (double)zero + sign * position * tpr / (2 * Py_MATH_PI) - (double)(self->ticks_per_rev * turns) +
                 (double)get(t, F[F_HOMING_OFFSET]);
  long long p, v, i;
  if (c->current_unit == 0.0 || self->velocity_unit == 0.0 || !clamped(ticks, F[F_PRESENT_POSITION], &p) ||
      !clamped(sign * velocity / self->velocity_unit, F[F_PRESENT_VELOCITY], &v) ||
      !clamped(sign * current / c->current_unit, F[F_PRESENT_CURRENT], &i))
    return 0;
  if (PyObject_SetAttr(servo, s_stale, Py_False) < 0) return -1;
  put(t, F[F_PRESENT_POSITION], p);
  put(t, F[F_PRESENT_VELOCITY], v);
  put(t, F[F_PRESENT_CURRENT], i);
  put(t, F[F_MOVING], (v < 0 ? -v : v) > get(t, F[F_MOVING_THRESHOLD]));
  return 1;
}

static PyObject* Chain_refresh(Chain* self, PyObject* unused) {
  (void)unused;
  if (!whole(self)) return PyLong_FromLongLong((1LL << self->n) - 1);
  long long general = 0;
  for (int k = 0; k < self->n; k++) {
    PyObject* stale = PyObject_GetAttr(self->servos[k], s_stale);
    if (!stale) return NULL;
    int is_stale = PyObject_IsTrue(stale);
    Py_DECREF(stale);
    if (is_stale < 0) return NULL;
    if (!is_stale) continue;
    int done = present(self, k);
    if (done < 0) return NULL;
    if (!done) general |= 1LL << k;
  }
  return PyLong_FromLongLong(general);
}

// Servo.clock(now) of servo k; 0 when its watchdog trips now or `now` is no float (left to
// Python), -1 on error
static int clock_one(Chain* self, int k, PyObject* now_obj, double now) {
  PyObject* servo = self->servos[k];
  const Field* F = self->fields;
  uint8_t* t = table_of(self, k);
  double ms = now * 1000;
  if (!isfinite(ms) || fabs(ms) >= 9.0e18) return 0;
  PyObject* heard_obj = PyObject_GetAttr(servo, s_heard_at);
  if (!heard_obj) return -1;
  double silent = 0.0;
  int heard_float = heard_obj == Py_None || PyFloat_CheckExact(heard_obj);
  if (heard_obj != Py_None && heard_float) silent = now - PyFloat_AS_DOUBLE(heard_obj);
  Py_DECREF(heard_obj);
  if (!heard_float) return 0;
  double period = (double)get(t, F[F_BUS_WATCHDOG]) * self->watchdog_unit;
  if (period > 0 && get(t, F[F_TORQUE_ENABLE]) == 1 && silent > period) return 0;     // it trips: Python
  if (PyObject_SetAttr(servo, s_clocked_at, now_obj) < 0) return -1;
  long long tick = (long long)ms % 32768;      // int() truncates; Python's % is never negative
  put(t, F[F_REALTIME_TICK], tick < 0 ? tick + 32768 : tick);
  return 1;
}

// whether servo k was clocked at `now` already (clocked_at == now)
static int clocked_at(Chain* self, int k, PyObject* now_obj) {
  PyObject* at = PyObject_GetAttr(self->servos[k], s_clocked_at);
  if (!at) return -1;
  int same = PyObject_RichCompareBool(at, now_obj, Py_EQ);
  Py_DECREF(at);
  return same;
}

// every servo clocked at `now` (DynamixelWire.tick), or first told it heard a packet then (Servo.heard)
static PyObject* clock_every(Chain* self, PyObject* now_obj, int heard) {
  if (!PyFloat_CheckExact(now_obj) || !whole(self))             // not a float: Python's
    return PyLong_FromLongLong((1LL << self->n) - 1);
  double now = PyFloat_AS_DOUBLE(now_obj);
  long long general = 0;
  for (int k = 0; k < self->n; k++) {
    if (heard && PyObject_SetAttr(self->servos[k], s_heard_at, now_obj) < 0) return NULL;
    int same = clocked_at(self, k, now_obj);
    if (same < 0) return NULL;
    if (same) continue;
    int done = clock_one(self, k, now_obj, now);
    if (done < 0) return NULL;
    if (!done) general |= 1LL << k;
  }
  return PyLong_FromLongLong(general);
}

static PyObject* Chain_clock(Chain* self, PyObject* now_obj) { return clock_every(self, now_obj, 0); }

static PyObject* Chain_heard(Chain* self, PyObject* now_obj) { return clock_every(self, now_obj, 1); }

// whether servo k listens to `id` as a broadcast write's block does (DynamixelWire._writes): by its
// ID, or by its Secondary ID where that differs
static inline int listens(const uint8_t* t, const Field* F, long long id) {
  long long primary = get(t, F[F_ID]), secondary = get(t, F[F_SECONDARY_ID]);
  return primary == id || (secondary != primary && secondary == id);
}

// DynamixelWire._writes of a SYNC WRITE's parameters whose span is one item that only the rule
// checks (Servo._check_value): rule = (signed, goal, low, high, mask, limit) where low/high, mask
// and limit (the limit item's (address, size, signed)) are None when the item has none. -1 when
// the parameters are not whole blocks (Python's: it refuses them), else the writes applied.
static PyObject* Chain_write(Chain* self, PyObject* args) {
  Py_buffer params;
  int is_signed, goal;
  PyObject *low_obj, *high_obj, *mask_obj, *limit_obj;
  if (!PyArg_ParseTuple(args, "y*(ppOOOO)", &params, &is_signed, &goal, &low_obj, &high_obj, &mask_obj, &limit_obj))
    return NULL;
  const uint8_t* p = (const uint8_t*)params.buf;
  Py_ssize_t size = params.len;
  long long low = 0, high = 0, mask = 0;
  int has_range = low_obj != Py_None, has_mask = mask_obj != Py_None, has_limit = limit_obj != Py_None;
  Field limit = {0, 1, 0};
  if ((has_range && (((low = PyLong_AsLongLong(low_obj)) == -1 && PyErr_Occurred()) ||
                     ((high = PyLong_AsLongLong(high_obj)) == -1 && PyErr_Occurred()))) ||
      (has_mask && (mask = PyLong_AsLongLong(mask_obj)) == -1 && PyErr_Occurred()) ||
      (has_limit && !PyArg_ParseTuple(limit_obj, "iip", &limit.address, &limit.size, &limit.is_signed))) {
    PyBuffer_Release(&params);
    return NULL;
  }
  if (size < 4 || !whole(self)) {
    PyBuffer_Release(&params);
    return PyLong_FromLong(-1);
  }
  Field item = {p[0] | (p[1] << 8), p[2] | (p[3] << 8), is_signed};
  Py_ssize_t step = 1 + item.size, body = size - 4;
  if (item.size == 0 || item.size > 4 || item.size == 3 || body == 0 || body % step) {
    PyBuffer_Release(&params);
    return PyLong_FromLong(-1);
  }
  const Field* F = self->fields;
  long written = 0;
  for (Py_ssize_t b = 4; b < size; b += step) {
    long long id = p[b];
    // the value as the item's field reads it from the block's data (Servo._check_write)
    uint8_t data[4] = {0, 0, 0, 0};
    memcpy(data, p + b + 1, (size_t)item.size);
    Field at_zero = {0, item.size, item.is_signed};
    long long value = get(data, at_zero);
    for (int k = 0; k < self->n; k++) {
      uint8_t* t = table_of(self, k);
      if (!listens(t, F, id)) continue;
      if (goal && get(t, F[F_BUS_WATCHDOG]) == -1) continue;              // tripped: goals refused
      if (has_range && !(low <= value && value <= high)) continue;
      if (has_mask && (value & ~mask)) continue;
      if (has_limit && (value < 0 ? -value : value) > get(t, limit)) continue;
      if (item.address + item.size > PyByteArray_GET_SIZE(self->tables[k])) continue;
      memcpy(t + item.address, data, (size_t)item.size);
      if (PyObject_SetAttr(self->servos[k], s_stale, Py_True) < 0) {
        PyBuffer_Release(&params);
        return NULL;
      }
      written++;
    }
  }
  PyBuffer_Release(&params);
  return PyLong_FromLong(written);
}

// DynamixelWire._fast_reads of one address and length for every servo of `ids` (bytes), into the
// reply laid out in `frame` with block k at starts[k]: -1 when nobody answers (a listed servo
// missing or not answering reads), -2 when it is Python's (a servo's Present registers stale and
// not to be written here, more than 256 IDs), else how many blocks were filled (a silent servo
// cuts the reply).
static PyObject* Chain_fast_read(Chain* self, PyObject* args) {
  Py_buffer ids, frame;
  int address, length, alert_bit, access_error;
  PyObject* starts;
  if (!PyArg_ParseTuple(args, "y*iiw*O!ii", &ids, &address, &length, &frame, &PyList_Type, &starts, &alert_bit,
                        &access_error))
    return NULL;
  const uint8_t* want = (const uint8_t*)ids.buf;
  uint8_t* out = (uint8_t*)frame.buf;
  const Field* F = self->fields;
  int order[256];
  long answering = 0, result = 0;
  if (ids.len > 256 || !whole(self)) {
    result = -2;
    goto done;
  }
  for (Py_ssize_t j = 0; j < ids.len; j++) {
    int found = -1;
    for (int k = 0; k < self->n && found < 0; k++)
      if (get(table_of(self, k), F[F_ID]) == want[j]) found = k;
    if (found >= 0) {
      PyObject* silent = PyObject_GetAttr(self->servos[found], s_silent);
      if (!silent) goto error;
      int is_silent = PyObject_IsTrue(silent);
      Py_DECREF(silent);
      if (is_silent < 0) goto error;
      if (is_silent) break;
    }
    long long level = found >= 0 ? get(table_of(self, found), F[F_STATUS_RETURN_LEVEL]) : 0;
    if (found < 0 || !(level == 2 || level == 1)) {
      result = -1;
      goto done;
    }
    order[answering++] = found;
  }
  if (PyList_GET_SIZE(starts) < answering + 1) {
    PyErr_SetString(PyExc_ValueError, "Chain.fast_read: a start for every block and the end");
    goto error;
  }
  for (long j = 0; j < answering; j++) {
    if (address + length > PyByteArray_GET_SIZE(self->tables[order[j]])) continue;   // refused before (read_into)
    PyObject* stale = PyObject_GetAttr(self->servos[order[j]], s_stale);
    if (!stale) goto error;
    int is_stale = PyObject_IsTrue(stale);
    Py_DECREF(stale);
    if (is_stale < 0) goto error;
    if (is_stale) {
      int done = present(self, order[j]);
      if (done < 0) goto error;
      if (!done) {
        result = -2;
        goto done;
      }
    }
  }
  for (long j = 0; j < answering; j++) {
    int k = order[j];
    uint8_t* t = table_of(self, k);
    long start = PyLong_AsLong(PyList_GET_ITEM(starts, j));
    if (start < 0 || start + 2 + length > frame.len) {
      if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "Chain.fast_read: a block outside the frame");
      goto error;
    }
    int error = 0;
    if (address + length > PyByteArray_GET_SIZE(self->tables[k])) {
      memset(out + start + 2, 0, (size_t)length);
      error = access_error;
    } else {
      memcpy(out + start + 2, t + address, (size_t)length);
    }
    out[start] = (uint8_t)(error | (get(t, F[F_HARDWARE_ERROR_STATUS]) != 0 ? alert_bit : 0));
  }
  result = answering;
done:
  PyBuffer_Release(&ids);
  PyBuffer_Release(&frame);
  return PyLong_FromLong(result);
error:
  PyBuffer_Release(&ids);
  PyBuffer_Release(&frame);
  return NULL;
}

// Servo.output_torque (Mechanics.torque) of servos start, start + 1, ... for their currents and
// horn speeds, up to the first one left to Python (its Mechanics not of the type given, or a zero
// coulomb_velocity Python divides by): its index, n when none. `parameters` names the Mechanics
// fields in the order read here (torque_constant, gear_efficiency, viscous_friction,
// coulomb_friction, coulomb_velocity).
static PyObject* Chain_torques(Chain* self, PyObject* args) {
  PyObject *c_obj, *v_obj, *t_obj, *kind, *names;
  int start;
  if (!PyArg_ParseTuple(args, "OOOiOO!", &c_obj, &v_obj, &t_obj, &start, &kind, &PyTuple_Type, &names)) return NULL;
  if (PyTuple_GET_SIZE(names) != 5) {
    PyErr_SetString(PyExc_ValueError, "Chain.torques: five Mechanics fields");
    return NULL;
  }
  Py_buffer view[3];
  if (!three(self, c_obj, v_obj, t_obj, view, 1)) return NULL;
  const double* current = (const double*)view[0].buf;
  const double* velocity = (const double*)view[1].buf;
  double* torque = (double*)view[2].buf;
  int k = start < 0 ? 0 : start, failed = 0;
  for (; k < self->n; k++) {
    PyObject* mechanics = PyObject_GetAttr(self->servos[k], s_mechanics);
    if (!mechanics) {
      failed = 1;
      break;
    }
    double p[5];
    int ok = Py_TYPE(mechanics) == (PyTypeObject*)kind;
    for (int i = 0; i < 5 && ok; i++) {
      PyObject* value = PyObject_GetAttr(mechanics, PyTuple_GET_ITEM(names, i));
      if (!value) {
        failed = 1;
        break;
      }
      ok = PyFloat_CheckExact(value);
      if (ok) p[i] = PyFloat_AS_DOUBLE(value);
      Py_DECREF(value);
    }
    Py_DECREF(mechanics);
    if (failed || !ok || p[4] == 0.0) break;
    double v = velocity[k];
    double friction = p[2] * v + p[3] * tanh(v / p[4]);
    torque[k] = current[k] * p[0] * p[1] - friction;
  }
  release(view);
  if (failed) return NULL;
  return PyLong_FromLong(k);
}

static PyMethodDef Chain_methods[] = {
    {"currents", (PyCFunction)Chain_currents, METH_VARARGS,
     "currents(position, velocity, out, start) -> k: Servo.output_current of servos start.. up to k"},
    {"torques", (PyCFunction)Chain_torques, METH_VARARGS,
     "torques(current, velocity, out, start, Mechanics, fields) -> k: Servo.output_torque of servos start.. up to k"},
    {"publish", (PyCFunction)Chain_publish, METH_VARARGS,
     "publish(position, velocity, current): Servo.set_present of every servo"},
    {"refresh", (PyCFunction)Chain_refresh, METH_NOARGS,
     "refresh() -> general: the Present registers of every stale servo"},
    {"clock", (PyCFunction)Chain_clock, METH_O, "clock(now) -> general: every servo not clocked at now"},
    {"heard", (PyCFunction)Chain_heard, METH_O, "heard(now) -> general: Servo.heard of every servo"},
    {"write", (PyCFunction)Chain_write, METH_VARARGS,
     "write(params, rule) -> written, or -1: a SYNC WRITE of one item checked by its rule"},
    {"fast_read", (PyCFunction)Chain_fast_read, METH_VARARGS,
     "fast_read(ids, address, length, frame, starts, alert_bit, access_error) -> blocks filled, -1 none, -2 Python's"},
    {NULL, NULL, 0, NULL},
};

static PyTypeObject ChainType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "servodyn.sim.dynamixel._chain.Chain",
    .tp_basicsize = sizeof(Chain),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "The servos of a simulated chain, their per-tick work at once (see the module's header).",
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Chain_init,
    .tp_dealloc = (destructor)Chain_dealloc,
    .tp_methods = Chain_methods,
};

static struct PyModuleDef chain_module = {
    PyModuleDef_HEAD_INIT, "_chain", "The simulated servos' per-tick work over a chain, in C.", -1, NULL,
};

PyMODINIT_FUNC PyInit__chain(void) {
  if (PyType_Ready(&ChainType) < 0) return NULL;
  s_stale = PyUnicode_InternFromString("_stale");
  s_shaft = PyUnicode_InternFromString("_shaft");
  s_turns = PyUnicode_InternFromString("_turns");
  s_zero_ticks = PyUnicode_InternFromString("zero_ticks");
  s_clocked_at = PyUnicode_InternFromString("clocked_at");
  s_heard_at = PyUnicode_InternFromString("_heard_at");
  s_silent = PyUnicode_InternFromString("silent");
  s_pid = PyUnicode_InternFromString("_pid");
  s_reset = PyUnicode_InternFromString("reset");
  s_mechanics = PyUnicode_InternFromString("mechanics");
  if (!s_stale || !s_shaft || !s_turns || !s_zero_ticks || !s_clocked_at || !s_heard_at || !s_silent || !s_pid ||
      !s_reset || !s_mechanics)
    return NULL;
  PyObject* mod = PyModule_Create(&chain_module);
  if (!mod) return NULL;
  PyObject* names = PyTuple_New(N_FIELDS);
  if (!names) {
    Py_DECREF(mod);
    return NULL;
  }
  for (int f = 0; f < N_FIELDS; f++) {
    PyObject* name = PyUnicode_FromString(FIELD_NAMES[f]);
    if (!name) {
      Py_DECREF(names);
      Py_DECREF(mod);
      return NULL;
    }
    PyTuple_SET_ITEM(names, f, name);
  }
  if (PyModule_AddObject(mod, "FIELDS", names) < 0) {
    Py_DECREF(names);
    Py_DECREF(mod);
    return NULL;
  }
  Py_INCREF(&ChainType);
  if (PyModule_AddObject(mod, "Chain", (PyObject*)&ChainType) < 0) {
    Py_DECREF(&ChainType);
    Py_DECREF(mod);
    return NULL;
  }
  return mod;
}
