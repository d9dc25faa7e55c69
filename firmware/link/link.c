// link.c: the host link (link.h): COBS framing with the Dynamixel CRC-16, the streaming decoder,
// every message's layout (written once, for pack and unpack alike), the controller's retransmit
// rule and the robot loaded over the link.
#include "link.h"

#include <string.h>

#include "canmotor.h"
#include "dxl.h"

//---------------------------------- framing ------------------------------------------------------

// COBS written on the fly, in one pass with the CRC: out[code_at] is the current block's code byte,
// filled in when a 00 (or the frame) ends it. A raw frame is at most LINK_MAX_RAW < 254 bytes, so a
// block never reaches COBS's 254 data bytes: the overhead is one byte, and a frame's wire length is
// known before it is written.
_Static_assert(LINK_MAX_RAW < 254, "one COBS block a frame");

typedef struct cobs_ {
  uint8_t* out;
  size_t n, code_at;
} cobs;

static uint16_t cobs_crc_run(cobs* c, const uint8_t* p, size_t k, uint16_t crc) {
  uint8_t* out = c->out;
  size_t n = c->n, at = c->code_at;
  for (size_t i = 0; i < k; i++) {
    uint8_t b = p[i];
    crc = dxl_crc_byte(crc, b);
    if (b) {
      out[n++] = b;
    } else {
      out[at] = (uint8_t)(n - at);
      at = n++;
    }
  }
  c->n = n;
  c->code_at = at;
  return crc;
}

size_t link_frame(uint8_t* out, size_t cap, uint8_t seq, uint8_t ack, uint8_t type,
                  const uint8_t* payload, size_t n) {
  if (n > LINK_MAX_PAYLOAD || cap < LINK_HEADER + n + LINK_CRC + 2u) return 0;
  uint8_t head[LINK_HEADER] = {LINK_VERSION, seq, ack, type, (uint8_t)n, (uint8_t)(n >> 8)};
  cobs c = {out, 1, 0};
  uint16_t crc = cobs_crc_run(&c, head, LINK_HEADER, 0);
  if (n) crc = cobs_crc_run(&c, payload, n, crc);
  uint8_t tail[LINK_CRC] = {(uint8_t)(crc >> 8), (uint8_t)crc};
  cobs_crc_run(&c, tail, LINK_CRC, 0);
  out[c.code_at] = (uint8_t)(c.n - c.code_at);
  out[c.n++] = 0;
  return c.n;
}

void link_decoder_reset(link_decoder* d) {
  d->n = 0;
  d->crc = 0;
  d->block = 0;
  d->code = 0;
  d->dropping = 0;
}

// the frame ended by a delimiter: its verdict
static int frame_end(link_decoder* d) {
  if (d->dropping) return LINK_BAD_TOO_LONG;
  if (d->block != 0 || d->n < LINK_HEADER + LINK_CRC) return LINK_BAD_SHORT;
  if (d->crc != 0) return LINK_BAD_CRC;
  d->version = d->raw[0];
  d->seq = d->raw[1];
  d->ack = d->raw[2];
  d->type = d->raw[3];
  d->len = dxl_get_u16(d->raw + 4);
  d->payload = d->raw + LINK_HEADER;
  if (d->version != LINK_VERSION) return LINK_BAD_VERSION;
  if (d->len != d->n - LINK_HEADER - LINK_CRC) return LINK_BAD_LENGTH;
  return LINK_FRAME;
}

// The decoder's state lives in locals through the bytes given (a tick takes its host's bytes in
// one call): one table lookup and a store a byte, whatever the COBS blocks' lengths (a knot's float
// zeros make them short). Every 00 ends a frame; an implied zero is a block's end, not a 00 byte.
int link_decoder_feed_bytes(link_decoder* d, const uint8_t* data, size_t n, size_t* used) {
  unsigned k = d->n, crc = d->crc, block = d->block, code = d->code, dropping = d->dropping;
  const uint16_t* table = dxl_crc_table;
  uint8_t* raw = d->raw;
  int verdict = LINK_MORE;
  size_t i = 0;
  while (i < n) {
    unsigned b = data[i++];
    if (b == 0) {
      d->n = (uint16_t)k, d->crc = (uint16_t)crc, d->block = (uint8_t)block, d->code = (uint8_t)code;
      d->dropping = (uint8_t)dropping;
      verdict = code == 0 && !dropping ? LINK_MORE : frame_end(d);
      link_decoder_reset(d);     // raw, so the payload, stays until the next frame's data bytes
      if (verdict != LINK_MORE) break;
      k = 0, crc = 0, block = 0, code = 0, dropping = 0;
      continue;
    }
    if (dropping) continue;
    if (block == 0) {            // a code byte: the previous block's implied zero, then a new block
      unsigned implied = code != 0 && code != 0xFF;
      code = b;
      block = b - 1;
      if (!implied) continue;
      b = 0;
    } else {
      block--;
    }
    if (k >= LINK_MAX_RAW) {
      dropping = 1;
      continue;
    }
    raw[k++] = (uint8_t)b;
    crc = ((crc << 8) ^ table[(crc >> 8) ^ b]) & 0xFFFFu;   // dxl_crc_byte, the table held in a register
  }
  if (verdict == LINK_MORE) {
    d->n = (uint16_t)k, d->crc = (uint16_t)crc, d->block = (uint8_t)block, d->code = (uint8_t)code;
    d->dropping = (uint8_t)dropping;
  }
  *used = i;
  return verdict;
}

int link_decoder_feed(link_decoder* d, uint8_t byte) {
  size_t used;
  return link_decoder_feed_bytes(d, &byte, 1, &used);
}

//---------------------------------- fields -------------------------------------------------------
// One layout function per message serves pack (write: struct -> bytes) and unpack (read).

typedef struct io_ {
  uint8_t* p;
  size_t n, cap;
  int write;        // 1: struct -> bytes, 0: bytes -> struct, TEXT: struct -> text (host only)
  int bad;          // ran past cap
  int saturated;    // a fixed-point value was clamped
#ifdef LINK_TEXT
  char* text;
  size_t tn, tcap;
#endif
} io;

// The layouts name their fields for link_describe (LINK_TEXT, host builds); the firmware keeps no names.
#ifdef LINK_TEXT
#include <stdarg.h>
#include <stdio.h>
#define NAME(s) s
enum { TEXT = 2 };

static void say(io* c, const char* fmt, ...) {
  if (c->write != TEXT || c->tn >= c->tcap) return;
  va_list ap;
  va_start(ap, fmt);
  int k = vsnprintf(c->text + c->tn, c->tcap - c->tn, fmt, ap);
  va_end(ap);
  if (k > 0) c->tn += (size_t)k;
}

static void say_name(io* c, const char* name, int first) {
  if (name) say(c, "%s%s=", c->tn ? " " : "", name);
  else if (!first) say(c, ",");
}
#define SAY_INT(c, name, v) do { if ((c)->write == TEXT) { say_name(c, name, 1); say(c, "%ld", (long)(v)); return; } } while (0)
#define SAY_REAL(c, name, v, first) do { if ((c)->write == TEXT) { say_name(c, name, first); say(c, "%.17g", (double)(v)); return; } } while (0)
#else
#define NAME(s) NULL
#define SAY_INT(c, name, v) (void)(name)
#define SAY_REAL(c, name, v, first) (void)(name)
#endif

static uint8_t* io_take(io* c, size_t k) {
  if (c->bad || c->n + k > c->cap) {
    c->bad = 1;
    return NULL;
  }
  uint8_t* at = c->p + c->n;
  c->n += k;
  return at;
}

static void io_u8(io* c, const char* name, uint8_t* v) {
  SAY_INT(c, name, *v);
  uint8_t* at = io_take(c, 1);
  if (!at) return;
  if (c->write) *at = *v;
  else *v = *at;
}

static void io_i8(io* c, const char* name, int8_t* v) {
  SAY_INT(c, name, *v);
  uint8_t u = (uint8_t)(*v < 0 ? *v + 256 : *v);
  io_u8(c, NULL, &u);
  if (!c->write) *v = (int8_t)(u < 0x80 ? u : u - 256);
}

static void io_u16(io* c, const char* name, uint16_t* v) {
  SAY_INT(c, name, *v);
  uint8_t* at = io_take(c, 2);
  if (!at) return;
  if (c->write) dxl_put_u16(at, *v);
  else *v = dxl_get_u16(at);
}

static void io_i16(io* c, const char* name, int16_t* v) {
  SAY_INT(c, name, *v);
  uint8_t* at = io_take(c, 2);
  if (!at) return;
  if (c->write) dxl_put_u16(at, (uint16_t)(*v < 0 ? *v + 65536 : *v));
  else *v = dxl_get_i16(at);
}

static void io_u32(io* c, const char* name, uint32_t* v) {
  SAY_INT(c, name, *v);
  uint8_t* at = io_take(c, 4);
  if (!at) return;
  if (c->write) dxl_put_u32(at, *v);
  else *v = dxl_get_u32(at);
}

static void io_str(io* c, const char* name, char* v, int k) {
#ifdef LINK_TEXT
  if (c->write == TEXT) {
    say_name(c, name, 1);
    say(c, "%.*s", k, v);
    return;
  }
#endif
  (void)name;
  for (int i = 0; i < k; i++) io_u8(c, NULL, (uint8_t*)&v[i]);
}

// name NULL: the next of an array (first: its first, which names it)
static void io_real_at(io* c, const char* name, int first, sd_real* v) {
  SAY_REAL(c, name, *v, first);
  (void)first;
  uint8_t* at = io_take(c, 4);
  if (!at) return;
  float f;
  uint32_t u;
  if (c->write) {
    f = (float)*v;
    memcpy(&u, &f, 4);
    dxl_put_u32(at, u);
  } else {
    u = dxl_get_u32(at);
    memcpy(&f, &u, 4);
    *v = (sd_real)f;
  }
}

static void io_real(io* c, const char* name, sd_real* v) { io_real_at(c, name, 1, v); }

static void io_reals(io* c, const char* name, sd_real* v, int k) {
  for (int i = 0; i < k; i++) io_real_at(c, i == 0 ? name : NULL, i == 0, v + i);
}

// value * scale rounded half away from zero into +-32767; -32768 for a NaN or an infinity
static int16_t fix_code(sd_real value, sd_real scale, int* saturated) {
  sd_real x = value * scale;
  if (!SD_ISFINITE(x)) {
    if (x == x) *saturated = 1;  // +-inf: clamped, below
    else return LINK_NAN_CODE;
  }
  if (x >= SD_R(32767.0)) {
    if (x > SD_R(32767.0)) *saturated = 1;
    return 32767;
  }
  if (x <= SD_R(-32767.0)) {
    if (x < SD_R(-32767.0)) *saturated = 1;
    return -32767;
  }
  return (int16_t)(x >= 0 ? (int)(x + SD_R(0.5)) : -(int)(SD_R(0.5) - x));
}

static void io_fix(io* c, const char* name, sd_real* v, sd_real scale) {
  SAY_REAL(c, name, *v, 1);
  int16_t code = 0;
  if (c->write) code = fix_code(*v, scale, &c->saturated);
  io_i16(c, NULL, &code);
  if (!c->write) *v = code == LINK_NAN_CODE ? (sd_real)NAN : (sd_real)code / scale;
}

//---------------------------------- the layouts --------------------------------------------------

static void hello_io(io* c, link_hello* m) { io_u16(c, NAME("nonce"), &m->nonce); }

static void hello_reply_io(io* c, link_hello_reply* m) {
  io_u16(c, NAME("nonce"), &m->nonce);
  io_u8(c, NAME("link_version"), &m->link_version);
  io_u8(c, NAME("fw_major"), &m->fw_major);
  io_u8(c, NAME("fw_minor"), &m->fw_minor);
  io_u8(c, NAME("fw_patch"), &m->fw_patch);
  io_str(c, NAME("board"), m->board, LINK_BOARD_NAME);
  io_u8(c, NAME("real_bytes"), &m->real_bytes);
  io_u8(c, NAME("max_body"), &m->max_body);
  io_u8(c, NAME("max_dof"), &m->max_dof);
  io_u16(c, NAME("knot_slots"), &m->knot_slots);
  io_u8(c, NAME("max_payload"), &m->max_payload);
  io_u8(c, NAME("window"), &m->window);
  io_u8(c, NAME("buses"), &m->buses);
  io_u8(c, NAME("state"), &m->state);
}

static void robot_head_io(io* c, link_robot_head* m) {
  io_u8(c, NAME("nbody"), &m->nbody);
  io_u8(c, NAME("ndof"), &m->ndof);
  io_u8(c, NAME("free_root"), &m->free_root);
  io_u8(c, NAME("mode"), &m->mode);
  io_u8(c, NAME("contact"), &m->contact);
  io_u8(c, NAME("contact_debounce"), &m->contact_debounce);
  io_u8(c, NAME("reaction"), &m->reaction);
  io_u16(c, NAME("update_ticks"), &m->update_ticks);
  io_u16(c, NAME("host_timeout_ms"), &m->host_timeout_ms);
  io_u32(c, NAME("period_us"), &m->period_us);
  io_reals(c, NAME("gravity"), m->gravity, 3);
  io_real(c, NAME("friction_speed"), &m->friction_speed);
  io_real(c, NAME("stall_time"), &m->stall_time);
  io_real(c, NAME("stall_speed"), &m->stall_speed);
  io_real(c, NAME("stall_share"), &m->stall_share);
  io_real(c, NAME("contact_arm_time"), &m->contact_arm_time);
  io_real(c, NAME("reaction_time"), &m->reaction_time);
}

static void body_io(io* c, link_body* m) {
  io_u8(c, NAME("index"), &m->index);
  io_i8(c, NAME("parent"), &m->parent);
  io_u8(c, NAME("dofnum"), &m->dofnum);
  io_u8(c, NAME("ball"), &m->ball);
  io_reals(c, NAME("pos"), m->pos, 3);
  io_reals(c, NAME("rot"), m->rot, 9);
  io_real(c, NAME("mass"), &m->mass);
  io_reals(c, NAME("com"), m->com, 3);
  io_reals(c, NAME("inertia"), m->inertia, 6);
}

static void joint_io(io* c, link_joint* m) {
  io_u8(c, NAME("index"), &m->index);
  io_u8(c, NAME("bus"), &m->bus);
  io_u8(c, NAME("id"), &m->id);
  io_u16(c, NAME("model_number"), &m->model_number);
  io_reals(c, NAME("dof_rot"), m->dof_rot, 9);
  io_real(c, NAME("armature"), &m->armature);
  io_real(c, NAME("direction"), &m->direction);
  io_real(c, NAME("zero_offset"), &m->zero_offset);
  io_real(c, NAME("gear_ratio"), &m->gear_ratio);
  io_real(c, NAME("rad_per_tick"), &m->rad_per_tick);
  io_real(c, NAME("radps_per_unit"), &m->radps_per_unit);
  io_real(c, NAME("effort_per_unit"), &m->effort_per_unit);
  io_real(c, NAME("nm_per_effort"), &m->nm_per_effort);
  io_real(c, NAME("effort_limit"), &m->effort_limit);
  io_real(c, NAME("q_min"), &m->q_min);
  io_real(c, NAME("q_max"), &m->q_max);
  io_real(c, NAME("qd_max"), &m->qd_max);
  io_real(c, NAME("tau_max"), &m->tau_max);
  io_real(c, NAME("friction_coulomb"), &m->friction_coulomb);
  io_real(c, NAME("friction_viscous"), &m->friction_viscous);
  io_real(c, NAME("kp"), &m->kp);
  io_real(c, NAME("kd"), &m->kd);
  io_real(c, NAME("error_lowpass"), &m->error_lowpass);
  io_real(c, NAME("following_error"), &m->following_error);
  io_real(c, NAME("observer_gain"), &m->observer_gain);
  io_real(c, NAME("observer_lowpass"), &m->observer_lowpass);
  io_real(c, NAME("contact_threshold"), &m->contact_threshold);
  io_u8(c, NAME("dialect"), &m->dialect);
  io_u16(c, NAME("reply_id"), &m->reply_id);
  io_reals(c, NAME("mit_range"), m->mit_range, 5);
}

static void command_io(io* c, link_command* m) {
  io_u8(c, NAME("command"), &m->command);
  io_u32(c, NAME("arg"), &m->arg);
}

static void result_io(io* c, link_result* m) {
  io_u8(c, NAME("seq"), &m->seq);
  io_u8(c, NAME("type"), &m->type);
  io_u8(c, NAME("stage"), &m->stage);
  io_i8(c, NAME("code"), &m->code);
  io_i16(c, NAME("index"), &m->index);
  io_u16(c, NAME("credits"), &m->credits);
}

enum { TM_HEAD = 15, TM_JOINT = 14, TM_FLAGS_AT = 11, KNOTS_HEAD = 7 };

static void telemetry_io(io* c, link_telemetry* m) {
  io_u32(c, NAME("tick"), &m->tick);
  io_u16(c, NAME("work_us"), &m->work_us);
  io_u16(c, NAME("missed"), &m->missed);
  io_u8(c, NAME("state"), &m->state);
  io_u8(c, NAME("fault"), &m->fault);
  io_u8(c, NAME("fault_joint"), &m->fault_joint);
  io_u8(c, NAME("flags"), &m->flags);
  io_u16(c, NAME("credits"), &m->credits);
  io_u8(c, NAME("njoint"), &m->njoint);
  if (m->njoint > LINK_MAX_TELEMETRY_JOINT) {
    c->bad = 1;
    return;
  }
  for (int j = 0; j < m->njoint; j++) {
    link_joint_tm* t = &m->joint[j];
    io_fix(c, NAME("q"), &t->q, SD_R(1.0) / LINK_LSB_Q);
    io_fix(c, NAME("qd"), &t->qd, SD_R(1.0) / LINK_LSB_QD);
    io_fix(c, NAME("q_d"), &t->q_d, SD_R(1.0) / LINK_LSB_Q);
    io_fix(c, NAME("tau"), &t->tau, SD_R(1.0) / LINK_LSB_TAU);
    io_i16(c, NAME("effort"), &t->effort);
    io_i16(c, NAME("command"), &t->command);
    io_fix(c, NAME("residual"), &t->residual, SD_R(1.0) / LINK_LSB_TAU);
  }
}

static void knots_io(io* c, link_knots* m) {
  io_u32(c, NAME("first"), &m->first);
  io_u8(c, NAME("ndof"), &m->ndof);
  io_u8(c, NAME("count"), &m->count);
  io_u8(c, NAME("flags"), &m->flags);
}

static void knot_io(io* c, int ndof, int flags, link_knot* k) {
  io_u32(c, NAME("t_us"), &k->t_us);
  io_reals(c, NAME("q"), k->q, ndof);
  io_reals(c, NAME("qd"), k->qd, ndof);
  io_reals(c, NAME("qdd"), k->qdd, ndof);
  if (flags & LINK_KNOT_GAINS) {
    io_reals(c, NAME("kp"), k->kp, ndof);
    io_reals(c, NAME("kd"), k->kd, ndof);
  }
}

// pack: the layout writes from the struct (write mode only reads it, hence the cast)
#define LINK_PACK(name, type)                                              \
  size_t link_pack_##name(uint8_t* p, size_t cap, const type* m) {         \
    io c = {.p = p, .cap = cap, .write = 1};                                           \
    name##_io(&c, (type*)m);                                               \
    return c.bad ? 0 : c.n;                                                \
  }                                                                        \
  int link_unpack_##name(const uint8_t* p, size_t n, type* m) {            \
    io c = {.p = (uint8_t*)p, .cap = n, .write = 0};                                   \
    name##_io(&c, m);                                                      \
    return c.bad || c.n != n ? LINK_E_PAYLOAD : LINK_OK;                   \
  }

LINK_PACK(hello, link_hello)
LINK_PACK(hello_reply, link_hello_reply)
LINK_PACK(robot_head, link_robot_head)
LINK_PACK(body, link_body)
LINK_PACK(joint, link_joint)
LINK_PACK(command, link_command)
LINK_PACK(result, link_result)

size_t link_pack_telemetry(uint8_t* p, size_t cap, const link_telemetry* m) {
  io c = {.p = p, .cap = cap, .write = 1};
  telemetry_io(&c, (link_telemetry*)m);
  if (c.bad) return 0;
  if (c.saturated) p[TM_FLAGS_AT] |= LINK_TM_SATURATED;
  return c.n;
}

int link_unpack_telemetry(const uint8_t* p, size_t n, link_telemetry* m) {
  io c = {.p = (uint8_t*)p, .cap = n, .write = 0};
  telemetry_io(&c, m);
  return c.bad || c.n != n ? LINK_E_PAYLOAD : LINK_OK;
}

size_t link_knot_bytes(int ndof, int flags) {
  return 4u + 4u * (size_t)ndof * (flags & LINK_KNOT_GAINS ? 5u : 3u);
}

static int knots_shape_ok(const link_knots* m) {
  return m->ndof >= 1 && m->ndof <= SD_MAX_DOF && m->count >= 1 &&
         (m->flags & ~(LINK_KNOT_GAINS | LINK_KNOT_LAST)) == 0;
}

size_t link_pack_knots(uint8_t* p, size_t cap, const link_knots* m, const link_knot* knots) {
  if (!knots_shape_ok(m)) return 0;
  io c = {.p = p, .cap = cap < LINK_MAX_PAYLOAD ? cap : LINK_MAX_PAYLOAD, .write = 1};
  knots_io(&c, (link_knots*)m);
  for (int k = 0; k < m->count; k++) knot_io(&c, m->ndof, m->flags, (link_knot*)&knots[k]);
  return c.bad ? 0 : c.n;
}

int link_unpack_knots(const uint8_t* p, size_t n, link_knots* m) {
  io c = {.p = (uint8_t*)p, .cap = n, .write = 0};
  knots_io(&c, m);
  if (c.bad || !knots_shape_ok(m)) return LINK_E_PAYLOAD;
  return n == KNOTS_HEAD + m->count * link_knot_bytes(m->ndof, m->flags) ? LINK_OK : LINK_E_PAYLOAD;
}

void link_knot_at(const uint8_t* p, const link_knots* m, int k, link_knot* out) {
  size_t at = KNOTS_HEAD + (size_t)k * link_knot_bytes(m->ndof, m->flags);
  io c = {.p = (uint8_t*)p + at, .cap = link_knot_bytes(m->ndof, m->flags), .write = 0};
  knot_io(&c, m->ndof, m->flags, out);
}

//---------------------------------- the controller's retransmit rule -----------------------------

void link_server_reset(link_server* s) { memset(s, 0, sizeof *s); }

int link_server_accept(link_server* s, uint8_t seq, uint8_t type, link_result* reply) {
  if (type == LINK_HELLO) {
    link_server_reset(s);
    s->started = 1;
    s->expected = seq;
    return LINK_EXECUTE;
  }
  if (s->started && seq == s->expected) return LINK_EXECUTE;
  uint8_t behind = (uint8_t)(s->expected - seq);
  int slot = seq % LINK_WINDOW;
  if (s->started && behind >= 1 && behind <= LINK_WINDOW && s->kept[slot] &&
      s->result[slot].seq == seq && s->result[slot].type == type) {
    *reply = s->result[slot];
    return LINK_REPEAT;
  }
  link_result nak = {seq, type, LINK_STAGE_LINK, LINK_E_ORDER, -1, 0};
  *reply = nak;
  return LINK_REFUSE;
}

void link_server_done(link_server* s, const link_result* result) {
  int slot = result->seq % LINK_WINDOW;
  s->result[slot] = *result;
  s->kept[slot] = 1;
  s->expected = (uint8_t)(result->seq + 1);
}

//---------------------------------- the knot buffer ----------------------------------------------

static void verdict(link_result* r, int stage, int code, int index) {
  r->stage = (uint8_t)stage;
  r->code = (int8_t)code;
  r->index = (int16_t)index;
}


void link_ring_reset(link_ring* r, int ndof, int slots) {
  r->slots = (uint16_t)(slots < 1 ? 1 : slots > SD_MAX_KNOT ? SD_MAX_KNOT : slots);
  r->head = r->count = 0;
  r->next = 0;
  r->last_t_us = 0;
  r->ndof = (uint8_t)ndof;
  r->ended = 0;
}

uint16_t link_ring_free(const link_ring* r) { return (uint16_t)(r->slots - r->count); }

const link_knot* link_ring_at(const link_ring* r, int k) {
  if (k < 0 || k >= r->count) return NULL;
  return &r->knot[(r->head + k) % r->slots];
}

void link_ring_pop(link_ring* r) {
  if (!r->count) return;
  r->head = (uint16_t)((r->head + 1) % r->slots);
  r->count--;
}

void link_ring_push(link_ring* r, const uint8_t* payload, size_t n, link_result* result) {
  link_knots m;
  verdict(result, LINK_STAGE_LINK, LINK_OK, -1);
  if (link_unpack_knots(payload, n, &m) != LINK_OK || m.ndof != r->ndof) {
    verdict(result, LINK_STAGE_LINK, LINK_E_PAYLOAD, -1);
  } else if (r->ended) {
    verdict(result, LINK_STAGE_LINK, LINK_E_STATE, -1);
  } else if (m.first != r->next) {
    verdict(result, LINK_STAGE_LINK, LINK_E_KNOT, (int)(r->next & 0x7FFF));
  } else if (m.count > link_ring_free(r)) {
    verdict(result, LINK_STAGE_LINK, LINK_E_FULL, -1);
  } else {
    uint32_t t = r->last_t_us;
    for (int k = 0; k < m.count; k++) {   // every time checked before any knot is taken
      uint32_t tk = dxl_get_u32(payload + KNOTS_HEAD + (size_t)k * link_knot_bytes(m.ndof, m.flags));
      if ((r->next > 0 || k > 0) && tk <= t) {
        verdict(result, LINK_STAGE_LINK, LINK_E_KNOT, (int)((m.first + (uint32_t)k) & 0x7FFF));
        break;
      }
      t = tk;
    }
  }
  if (result->code == LINK_OK) {
    for (int k = 0; k < m.count; k++) {
      link_knot* slot = &r->knot[(r->head + r->count) % r->slots];
      link_knot_at(payload, &m, k, slot);
      if (!(m.flags & LINK_KNOT_GAINS)) {   // no gains: the controller's own (zero marks none)
        memset(slot->kp, 0, sizeof slot->kp);
        memset(slot->kd, 0, sizeof slot->kd);
      }
      r->count++;
      r->last_t_us = slot->t_us;
    }
    r->next += m.count;
    r->ended = (m.flags & LINK_KNOT_LAST) != 0;
  }
  result->credits = link_ring_free(r);
}

//---------------------------------- a robot loaded over the link ---------------------------------

void link_robot_begin(link_robot* r, const link_robot_head* head, link_result* result) {
  memset(r, 0, sizeof *r);
  if (head->nbody < 1 || head->nbody > SD_MAX_BODY || head->ndof < 1 || head->ndof > SD_MAX_DOF) {
    verdict(result, LINK_STAGE_LINK, LINK_E_SIZE, -1);
    return;
  }
  r->head = *head;
  r->begun = 1;
  verdict(result, LINK_STAGE_LINK, LINK_OK, -1);
}

void link_robot_body(link_robot* r, const link_body* b, link_result* result) {
  if (!r->begun) { verdict(result, LINK_STAGE_LINK, LINK_E_STATE, b->index); return; }
  if (b->index >= r->head.nbody) { verdict(result, LINK_STAGE_LINK, LINK_E_SIZE, b->index); return; }
  sd_model* m = &r->model;
  int i = b->index;
  m->body_parent[i] = b->parent;
  m->body_dofnum[i] = b->dofnum;
  m->body_ball[i] = b->ball;
  memcpy(m->body_pos[i], b->pos, sizeof b->pos);
  memcpy(m->body_rot[i], b->rot, sizeof b->rot);
  m->body_mass[i] = b->mass;
  memcpy(m->body_com[i], b->com, sizeof b->com);
  memcpy(m->body_inertia[i], b->inertia, sizeof b->inertia);
  r->body_seen[i] = 1;
  r->ready = 0;
  verdict(result, LINK_STAGE_LINK, LINK_OK, i);
}

void link_robot_joint(link_robot* r, const link_joint* j, link_result* result) {
  if (!r->begun) { verdict(result, LINK_STAGE_LINK, LINK_E_STATE, j->index); return; }
  if (j->index >= r->head.ndof) { verdict(result, LINK_STAGE_LINK, LINK_E_SIZE, j->index); return; }
  r->joint[j->index] = *j;
  r->joint_seen[j->index] = 1;
  r->ready = 0;
  verdict(result, LINK_STAGE_LINK, LINK_OK, j->index);
}

static int finite_positive(sd_real x) { return SD_ISFINITE(x) && x > 0; }

// a CAN motor's MIT ranges: each end within the codec's (hal/can/c/canmotor.h)
static int can_ranges_ok(const sd_real* range) {
  for (int k = 0; k < 5; k++)
    if (!(SD_ISFINITE(range[k]) && range[k] >= CM_RANGE_MIN && range[k] <= CM_RANGE_MAX)) return 0;
  return 1;
}

// the servo map and safety values of joint k (the core checks the rest)
static int servo_error(const link_robot* r, int k, uint8_t buses) {
  const link_joint* j = &r->joint[k];
  int unactuated = r->head.free_root && k < 6;
  if (unactuated) return j->bus == LINK_BUS_NONE ? 0 : LINK_SERVO_BUS;
  if (j->bus == LINK_BUS_NONE || j->bus > LINK_BUS_CAN || !(buses & (1u << j->bus))) return LINK_SERVO_BUS;
  if (j->direction != SD_R(1.0) && j->direction != SD_R(-1.0)) return LINK_SERVO_DIRECTION;
  int can = j->bus == LINK_BUS_CAN;
  if (can != (j->dialect != LINK_DIALECT_NONE)) return can ? LINK_SERVO_CAN : LINK_SERVO_BUS;
  if (can && (j->dialect >= LINK_NDIALECT || j->reply_id > 0x7FF || !can_ranges_ok(j->mit_range)))
    return LINK_SERVO_CAN;
  if (!finite_positive(j->gear_ratio) || !finite_positive(j->nm_per_effort) || !SD_ISFINITE(j->zero_offset) ||
      (!can && (!finite_positive(j->rad_per_tick) || !finite_positive(j->radps_per_unit) ||
                !finite_positive(j->effort_per_unit))))
    return LINK_SERVO_SCALE;
  if (!SD_ISFINITE(j->q_min) || !SD_ISFINITE(j->q_max) || !(j->q_min < j->q_max) ||
      !finite_positive(j->qd_max) || !finite_positive(j->effort_limit))
    return LINK_SERVO_RANGE;
  if (!finite_positive(j->following_error) || (r->head.contact && !finite_positive(j->contact_threshold)))
    return LINK_SERVO_SAFETY;
  for (int i = 0; i < k; i++)
    if (r->joint[i].bus == j->bus && r->joint[i].id == j->id) return LINK_SERVO_DUPLICATE;
  return 0;
}

static int table_ok(const link_robot_head* h) {
  return h->period_us > 0 && h->host_timeout_ms > 0 && h->reaction < LINK_NREACTION &&
         finite_positive(h->stall_time) && finite_positive(h->stall_speed) &&
         finite_positive(h->stall_share) && h->stall_share <= SD_R(1.0) && finite_positive(h->reaction_time) &&
         SD_ISFINITE(h->contact_arm_time) && h->contact_arm_time >= 0 && (!h->contact || h->contact_debounce >= 1);
}

void link_robot_commit(link_robot* r, uint8_t buses, link_result* result) {
  r->ready = 0;
  if (!r->begun) { verdict(result, LINK_STAGE_LINK, LINK_E_STATE, -1); return; }
  const link_robot_head* h = &r->head;
  for (int i = 0; i < h->nbody; i++)
    if (!r->body_seen[i]) { verdict(result, LINK_STAGE_LINK, LINK_E_INCOMPLETE, i); return; }
  for (int k = 0; k < h->ndof; k++)
    if (!r->joint_seen[k]) { verdict(result, LINK_STAGE_LINK, LINK_E_NO_JOINT, k); return; }

  sd_model* m = &r->model;
  m->nbody = h->nbody;
  m->ndof = h->ndof;
  m->free_root = h->free_root;
  memcpy(m->gravity, h->gravity, sizeof h->gravity);
  int next = 0;
  for (int i = 0; i < h->nbody; i++) {
    m->body_dofadr[i] = next;
    next += m->body_dofnum[i];
  }
  for (int k = 0; k < h->ndof; k++) {
    memcpy(m->dof_rot[k], r->joint[k].dof_rot, sizeof r->joint[k].dof_rot);
    m->dof_armature[k] = r->joint[k].armature;
  }
  int bad = -1;
  int code = sd_model_setup(m, &bad);
  if (code != SD_OK) { verdict(result, LINK_STAGE_MODEL, code, bad); return; }

  if (!table_ok(h)) { verdict(result, LINK_STAGE_SERVO, LINK_SERVO_SAFETY, -1); return; }
  for (int k = 0; k < h->ndof; k++) {
    code = servo_error(r, k, buses);
    if (code) { verdict(result, LINK_STAGE_SERVO, code, k); return; }
  }

  sd_control_config* c = &r->control;
  sd_observer_config* o = &r->observer;
  c->mode = h->mode;
  c->update_ticks = h->update_ticks;
  c->friction_speed = h->friction_speed;
  o->dt = (sd_real)h->period_us * SD_R(1e-6);
  o->friction_speed = h->friction_speed;
  for (int k = 0; k < h->ndof; k++) {
    const link_joint* j = &r->joint[k];
    c->kp[k] = j->kp;
    c->kd[k] = j->kd;
    c->tau_max[k] = j->tau_max;
    c->error_lowpass[k] = j->error_lowpass;
    c->friction_coulomb[k] = o->friction_coulomb[k] = j->friction_coulomb;
    c->friction_viscous[k] = o->friction_viscous[k] = j->friction_viscous;
    o->gain[k] = j->observer_gain;
    o->lowpass[k] = j->observer_lowpass;
  }
  code = sd_control_check(m, c);
  if (code != SD_CONTROL_OK) { verdict(result, LINK_STAGE_CONTROL, code, -1); return; }
  code = sd_observer_check(m, o);
  if (code != SD_OBSERVER_OK) { verdict(result, LINK_STAGE_OBSERVER, code, -1); return; }
  r->ready = 1;
  verdict(result, LINK_STAGE_LINK, LINK_OK, -1);
}

//---------------------------------- host-side helpers (LINK_TEXT) --------------------------------

#ifdef LINK_TEXT
static link_knot g_knots[LINK_MAX_PAYLOAD / 16];

int link_host_recode(uint8_t type, const uint8_t* p, size_t n, char* text, size_t tcap, uint8_t* out,
                     size_t ocap, size_t* on) {
  static union {
    link_hello h;
    link_hello_reply hr;
    link_robot_head rh;
    link_body b;
    link_joint j;
    link_command c;
    link_result r;
    link_telemetry t;
  } u;
  io t = {.write = TEXT, .text = text, .tcap = tcap};
  if (tcap) text[0] = 0;
  *on = 0;
  int rc;
  switch (type) {
#define RECODE(T, name, field)                         \
  case T:                                              \
    rc = link_unpack_##name(p, n, &u.field);           \
    if (rc) return rc;                                 \
    name##_io(&t, &u.field);                           \
    *on = link_pack_##name(out, ocap, &u.field);       \
    return LINK_OK;
    RECODE(LINK_HELLO, hello, h)
    RECODE(LINK_HELLO_REPLY, hello_reply, hr)
    RECODE(LINK_LOAD_ROBOT, robot_head, rh)
    RECODE(LINK_LOAD_BODY, body, b)
    RECODE(LINK_LOAD_JOINT, joint, j)
    RECODE(LINK_COMMAND, command, c)
    RECODE(LINK_RESULT, result, r)
    RECODE(LINK_TELEMETRY, telemetry, t)
#undef RECODE
    case LINK_COMMIT:
      return n == 0 ? LINK_OK : LINK_E_PAYLOAD;
    case LINK_KNOTS: {
      link_knots m;
      rc = link_unpack_knots(p, n, &m);
      if (rc) return rc;
      knots_io(&t, &m);
      for (int k = 0; k < m.count; k++) {
        link_knot_at(p, &m, k, &g_knots[k]);
        knot_io(&t, m.ndof, m.flags, &g_knots[k]);
      }
      *on = link_pack_knots(out, ocap, &m, g_knots);
      return LINK_OK;
    }
    default:
      return LINK_E_TYPE;
  }
}

size_t link_host_sizeof(int what) {
  return what == 0 ? sizeof(link_decoder) : what == 1 ? sizeof(link_server) : what == 2 ? sizeof(link_robot)
                                                                                        : sizeof(link_ring);
}

uint16_t link_host_ring_push(link_ring* r, const uint8_t* p, size_t n, uint8_t result[8]) {
  link_result res = {0, LINK_KNOTS, LINK_STAGE_LINK, LINK_OK, -1, 0};
  link_ring_push(r, p, n, &res);
  link_pack_result(result, 8, &res);
  return res.credits;
}

int link_host_feed(link_decoder* d, const uint8_t* data, size_t n, size_t* used, uint8_t head[4],
                   uint8_t* payload, uint16_t* len) {
  for (size_t i = 0; i < n; i++) {
    int v = link_decoder_feed(d, data[i]);
    if (v == LINK_MORE) continue;
    *used = i + 1;
    head[0] = d->version;
    head[1] = d->seq;
    head[2] = d->ack;
    head[3] = d->type;
    *len = 0;
    if (v == LINK_FRAME) {
      *len = d->len;
      memcpy(payload, d->payload, d->len);
    }
    return v;
  }
  *used = n;
  return LINK_MORE;
}

int link_host_accept(link_server* s, uint8_t seq, uint8_t type, uint8_t reply[8]) {
  link_result r;
  int action = link_server_accept(s, seq, type, &r);
  if (action != LINK_EXECUTE) link_pack_result(reply, 8, &r);
  return action;
}

void link_host_done(link_server* s, const uint8_t* result, size_t n) {
  link_result r;
  if (link_unpack_result(result, n, &r) == LINK_OK) link_server_done(s, &r);
}

uint8_t link_host_expected(const link_server* s) { return s->expected; }

int link_host_robot(link_robot* r, uint8_t type, const uint8_t* p, size_t n, uint8_t buses,
                    uint8_t result[8]) {
  static union {
    link_robot_head h;
    link_body b;
    link_joint j;
  } u;
  link_result res = {0, type, LINK_STAGE_LINK, LINK_E_PAYLOAD, -1, 0};
  if (type == LINK_LOAD_ROBOT && link_unpack_robot_head(p, n, &u.h) == LINK_OK) link_robot_begin(r, &u.h, &res);
  else if (type == LINK_LOAD_BODY && link_unpack_body(p, n, &u.b) == LINK_OK) link_robot_body(r, &u.b, &res);
  else if (type == LINK_LOAD_JOINT && link_unpack_joint(p, n, &u.j) == LINK_OK) link_robot_joint(r, &u.j, &res);
  else if (type == LINK_COMMIT && n == 0) link_robot_commit(r, buses, &res);
  link_pack_result(result, 8, &res);
  return res.code;
}
#endif  // LINK_TEXT
