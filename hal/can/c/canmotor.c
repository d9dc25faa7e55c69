// canmotor.c: see canmotor.h.
#include "canmotor.h"

#include <float.h>

#ifdef SD_SINGLE
#define CM_REAL_MAX FLT_MAX
#else
#define CM_REAL_MAX DBL_MAX
#endif

// a finite cm_real without <math.h>: NaN fails x == x, +-inf fails the bound
static int finite(cm_real x) { return x == x && x <= CM_REAL_MAX && x >= -CM_REAL_MAX; }

static cm_real clamp(cm_real x, cm_real lo, cm_real hi, int* hit) {
  if (x < lo) { *hit = 1; return lo; }
  if (x > hi) { *hit = 1; return hi; }
  return x;
}

static int range_ok(cm_real m) { return m >= CM_RANGE_MIN && m <= CM_RANGE_MAX; }   // NaN fails

static int ranges_ok(const cm_ranges* r) {
  return range_ok(r->p_max) && range_ok(r->v_max) && range_ok(r->t_max) && range_ok(r->kp_max) &&
         range_ok(r->kd_max);
}

// the largest code of a field of `bits` bits (1..16; 0 outside)
static uint32_t top_code(unsigned bits) { return bits >= 1 && bits <= 16 ? (1u << bits) - 1u : 0u; }

uint32_t cm_to_uint(cm_real x, cm_real lo, cm_real hi, unsigned bits) {
  uint32_t top = top_code(bits);
  cm_real scaled;
  if (!(x > lo)) return 0;              // below the range, and NaN
  if (x >= hi) return top;
  scaled = (x - lo) * (cm_real)top / (hi - lo);
  return scaled >= (cm_real)top ? top : (uint32_t)scaled;
}

cm_real cm_to_float(uint32_t u, cm_real lo, cm_real hi, unsigned bits) {
  uint32_t top = top_code(bits);
  return top ? (cm_real)u * (hi - lo) / (cm_real)top + lo : lo;
}

int cm_pack_command(const cm_ranges* r, const cm_command* c, uint8_t out[8], unsigned* clamped) {
  int hit[5] = {0, 0, 0, 0, 0};
  uint32_t p, v, kp, kd, t;
  unsigned bits = 0;
  if (!ranges_ok(r)) return CM_EVALUE;
  if (!finite(c->p) || !finite(c->v) || !finite(c->kp) || !finite(c->kd) || !finite(c->t))
    return CM_EVALUE;
  // clamp first: float_to_uint itself would wrap a value outside its range
  p = cm_to_uint(clamp(c->p, -r->p_max, r->p_max, &hit[0]), -r->p_max, r->p_max, 16);
  v = cm_to_uint(clamp(c->v, -r->v_max, r->v_max, &hit[1]), -r->v_max, r->v_max, 12);
  kp = cm_to_uint(clamp(c->kp, CM_R(0), r->kp_max, &hit[2]), CM_R(0), r->kp_max, 12);
  kd = cm_to_uint(clamp(c->kd, CM_R(0), r->kd_max, &hit[3]), CM_R(0), r->kd_max, 12);
  t = cm_to_uint(clamp(c->t, -r->t_max, r->t_max, &hit[4]), -r->t_max, r->t_max, 12);
  out[0] = (uint8_t)(p >> 8);
  out[1] = (uint8_t)(p & 0xFF);
  out[2] = (uint8_t)(v >> 4);
  out[3] = (uint8_t)(((v & 0xF) << 4) | (kp >> 8));
  out[4] = (uint8_t)(kp & 0xFF);
  out[5] = (uint8_t)(kd >> 4);
  out[6] = (uint8_t)(((kd & 0xF) << 4) | (t >> 8));
  out[7] = (uint8_t)(t & 0xFF);
  for (int k = 0; k < 5; k++) bits |= hit[k] ? (1u << k) : 0u;
  if (clamped) *clamped = bits;
  return CM_OK;
}

int cm_unpack_command(const cm_ranges* r, const uint8_t* data, size_t len, cm_command* c) {
  if (len != 8) return CM_ELEN;
  if (!ranges_ok(r)) return CM_EVALUE;
  if (cm_special(data, len)) return CM_EKIND;
  c->p = cm_to_float(((uint32_t)data[0] << 8) | data[1], -r->p_max, r->p_max, 16);
  c->v = cm_to_float(((uint32_t)data[2] << 4) | (data[3] >> 4), -r->v_max, r->v_max, 12);
  c->kp = cm_to_float(((uint32_t)(data[3] & 0xF) << 8) | data[4], CM_R(0), r->kp_max, 12);
  c->kd = cm_to_float(((uint32_t)data[5] << 4) | (data[6] >> 4), CM_R(0), r->kd_max, 12);
  c->t = cm_to_float(((uint32_t)(data[6] & 0xF) << 8) | data[7], -r->t_max, r->t_max, 12);
  return CM_OK;
}

void cm_pack_special(uint8_t out[8], uint8_t code) {
  for (int k = 0; k < 7; k++) out[k] = 0xFF;
  out[7] = code;
}

int cm_special(const uint8_t* data, size_t len) {
  if (len != 8) return 0;
  for (int k = 0; k < 7; k++)
    if (data[k] != 0xFF) return 0;
  switch (data[7]) {
    case CM_ENTER: case CM_EXIT: case CM_SET_ZERO: case CM_CLEAR_ERROR: return data[7];
    default: return 0;
  }
}

// p16, v12, t12 from bytes 1..5, as every dialect's reply has them
static int state_fields(const cm_ranges* r, const cm_reply* y, uint8_t* out) {
  int hit = 0;
  uint32_t p, v, t;
  if (!ranges_ok(r) || !finite(y->p) || !finite(y->v) || !finite(y->t)) return CM_EVALUE;
  p = cm_to_uint(clamp(y->p, -r->p_max, r->p_max, &hit), -r->p_max, r->p_max, 16);
  v = cm_to_uint(clamp(y->v, -r->v_max, r->v_max, &hit), -r->v_max, r->v_max, 12);
  t = cm_to_uint(clamp(y->t, -r->t_max, r->t_max, &hit), -r->t_max, r->t_max, 12);
  out[1] = (uint8_t)(p >> 8);
  out[2] = (uint8_t)(p & 0xFF);
  out[3] = (uint8_t)(v >> 4);
  out[4] = (uint8_t)(((v & 0xF) << 4) | (t >> 8));
  out[5] = (uint8_t)(t & 0xFF);
  return CM_OK;
}

static void read_state(const cm_ranges* r, const uint8_t* data, cm_reply* y) {
  y->p = cm_to_float(((uint32_t)data[1] << 8) | data[2], -r->p_max, r->p_max, 16);
  y->v = cm_to_float(((uint32_t)data[3] << 4) | (data[4] >> 4), -r->v_max, r->v_max, 12);
  y->t = cm_to_float(((uint32_t)(data[4] & 0xF) << 8) | data[5], -r->t_max, r->t_max, 12);
  y->temperature = y->temperature2 = 0;
  y->status = y->voltage = 0;
}

int cm_pack_mit_reply(const cm_ranges* r, const cm_reply* y, uint8_t out[6]) {
  out[0] = y->id;
  return state_fields(r, y, out);
}

int cm_unpack_mit_reply(const cm_ranges* r, const uint8_t* data, size_t len, cm_reply* y) {
  if (len != 6 && len != 7) return CM_ELEN;
  if (!ranges_ok(r)) return CM_EVALUE;
  read_state(r, data, y);
  y->id = data[0];
  y->voltage = len == 7 ? data[6] : 0;
  return CM_OK;
}

int cm_pack_damiao_feedback(const cm_ranges* r, const cm_reply* y, uint8_t out[8]) {
  out[0] = (uint8_t)(((y->status & 0xF) << 4) | (y->id & 0xF));
  out[6] = (uint8_t)y->temperature;
  out[7] = (uint8_t)y->temperature2;
  return state_fields(r, y, out);
}

int cm_unpack_damiao_feedback(const cm_ranges* r, const uint8_t* data, size_t len, cm_reply* y) {
  if (len != 8) return CM_ELEN;
  if (!ranges_ok(r)) return CM_EVALUE;
  read_state(r, data, y);
  y->id = data[0] & 0xF;
  y->status = data[0] >> 4;
  y->temperature = (int8_t)data[6];
  y->temperature2 = (int8_t)data[7];
  return CM_OK;
}

int cm_pack_cubemars_reply(const cm_ranges* r, const cm_reply* y, uint8_t out[8]) {
  out[0] = y->id;
  out[6] = (uint8_t)y->temperature;
  out[7] = y->status;
  return state_fields(r, y, out);
}

int cm_unpack_cubemars_reply(const cm_ranges* r, const uint8_t* data, size_t len, cm_reply* y) {
  if (len != 8) return CM_ELEN;
  if (!ranges_ok(r)) return CM_EVALUE;
  read_state(r, data, y);
  y->id = data[0];
  y->temperature = (int8_t)data[6];
  y->status = data[7];
  return CM_OK;
}

void cm_pack_register(const cm_register* g, uint8_t out[8]) {
  out[0] = (uint8_t)(g->can_id & 0xFF);
  out[1] = (uint8_t)(g->can_id >> 8);
  out[2] = g->cmd;
  out[3] = g->rid;
  for (int k = 0; k < 4; k++) out[4 + k] = (uint8_t)(g->value >> (8 * k));
}

int cm_unpack_register(const uint8_t* data, size_t len, cm_register* g) {
  // a refresh request (0xCC) has 4 bytes: id, cmd, rid 0
  if (len != 8 && len != 4) return CM_ELEN;
  switch (data[2]) {
    case CM_REG_READ: case CM_REG_WRITE: case CM_REG_STORE: case CM_REG_REFRESH: break;
    default: return CM_EKIND;
  }
  g->can_id = (uint16_t)(data[0] | (data[1] << 8));
  g->cmd = data[2];
  g->rid = data[3];
  g->value = 0;
  if (len == 8)
    for (int k = 0; k < 4; k++) g->value |= (uint32_t)data[4 + k] << (8 * k);
  return CM_OK;
}
