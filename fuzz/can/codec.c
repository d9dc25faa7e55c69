// codec.c: libFuzzer target for the CAN motor frame codec (hal/can/c/canmotor.c), built twice:
// build/fuzz/can_codec (cm_real = double, the host's) and build/fuzz/can32_codec (-DSD_SINGLE,
// the firmware's float). The input's first byte chooses what to do, the next bytes the MIT ranges
// (each a scaled 16-bit number, or any raw IEEE value: NaN, inf, huge, denormal, negative):
//
//   decode  the rest of the input is one frame of any length (in a buffer of exactly that size,
//           so AddressSanitizer sees a read past it), given to every decoder: command, special,
//           mit / Damiao / CubeMars replies, Damiao register frames. Each answers with its error for
//           a wrong length or kind, and a frame it decodes has every value finite and inside its
//           range and packs back to the same bytes, quantized fields within one code.
//   encode  a command and a reply's state from the input, each value scaled or raw, packed by
//           every encoder: non-finite values and bad ranges are refused; otherwise every field
//           decodes back inside its range, within one quantization step of the value clamped
//           into the range, and the clamp bits name exactly the fields that were outside.
#include "../check.h"
#include "canmotor.h"

#ifdef SD_SINGLE
#define EPS CM_R(1.1920929e-07)
#else
#define EPS CM_R(2.220446049250313e-16)
#endif

// one value: a mode byte; with its top bit a raw IEEE cm_real from the next bytes, else a signed
// 16-bit number over 64 (so the seeds write 12.5 or 28 exactly, in either precision)
static cm_real take_real(input* in) {
  uint8_t mode = take(in);
  if (mode & 0x80) {
    uint8_t raw[sizeof(cm_real)];
    for (size_t k = 0; k < sizeof raw; k++) raw[k] = take(in);
    cm_real x;
    memcpy(&x, raw, sizeof x);
    return x;
  }
  int16_t v = (int16_t)(take(in) | take(in) << 8);
  return (cm_real)v / CM_R(64.0);
}

static int finite(cm_real x) { return x - x == x - x; }

// the ranges the codec accepts (it must refuse every other)
static int ranges_valid(const cm_ranges* r) {
  const cm_real m[5] = {r->p_max, r->v_max, r->t_max, r->kp_max, r->kd_max};
  for (int k = 0; k < 5; k++)
    if (!finite(m[k]) || !(m[k] >= CM_RANGE_MIN) || !(m[k] <= CM_RANGE_MAX)) return 0;
  return 1;
}

typedef struct {
  cm_real lo, hi;
  unsigned bits;
} field;

static field field_of(const cm_ranges* r, int k) {
  switch (k) {
    case 0: return (field){-r->p_max, r->p_max, 16};
    case 1: return (field){-r->v_max, r->v_max, 12};
    case 2: return (field){CM_R(0.0), r->kp_max, 12};
    case 3: return (field){CM_R(0.0), r->kd_max, 12};
    default: return (field){-r->t_max, r->t_max, 12};
  }
}

static cm_real step_of(field f) { return (f.hi - f.lo) / (cm_real)((1u << f.bits) - 1u); }

// a decoded value: finite and inside its range (to the rounding of the decode)
static void check_inside(cm_real x, field f) {
  cm_real slack = CM_R(4.0) * EPS * (f.hi - f.lo);
  CHECK(finite(x));
  CHECK(x >= f.lo - slack && x <= f.hi + slack);
}

// a value packed and decoded back: within one step of the value clamped into the range
static void check_round_trip(cm_real sent, cm_real back, field f) {
  cm_real inside = sent < f.lo ? f.lo : sent > f.hi ? f.hi : sent;
  cm_real d = back > inside ? back - inside : inside - back;
  check_inside(back, f);
  CHECK(d <= step_of(f) * (CM_R(1.0) + CM_R(64.0) * EPS) + CM_R(8.0) * EPS * (f.hi - f.lo));
}

// the codes of a command frame's five fields, and of a reply's three (bytes 1..5)
static void command_codes(const uint8_t* d, uint32_t c[5]) {
  c[0] = (uint32_t)d[0] << 8 | d[1];
  c[1] = (uint32_t)d[2] << 4 | d[3] >> 4;
  c[2] = (uint32_t)(d[3] & 0xF) << 8 | d[4];
  c[3] = (uint32_t)d[5] << 4 | d[6] >> 4;
  c[4] = (uint32_t)(d[6] & 0xF) << 8 | d[7];
}

static void state_codes(const uint8_t* d, uint32_t c[3]) {
  c[0] = (uint32_t)d[1] << 8 | d[2];
  c[1] = (uint32_t)d[3] << 4 | d[4] >> 4;
  c[2] = (uint32_t)(d[4] & 0xF) << 8 | d[5];
}

static int within_one(uint32_t a, uint32_t b) { return a == b || a + 1 == b || b + 1 == a; }

static void check_reply(const cm_ranges* r, const cm_reply* y) {
  check_inside(y->p, field_of(r, 0));
  check_inside(y->v, field_of(r, 1));
  check_inside(y->t, field_of(r, 4));
}

// a decoded reply packed again: the same bytes, the state within one code a field
static void check_repacked(const uint8_t* data, const uint8_t* again, size_t n) {
  uint32_t a[3], b[3];
  state_codes(data, a);
  state_codes(again, b);
  for (int k = 0; k < 3; k++) CHECK(within_one(a[k], b[k]));
  CHECK(data[0] == again[0]);
  for (size_t k = 6; k < n; k++) CHECK(data[k] == again[k]);
}

static void decode(const cm_ranges* r, const uint8_t* data, size_t n) {
  int valid = ranges_valid(r);
  cm_command c;
  cm_reply y;
  cm_register g;
  uint8_t again[8];

  int special = cm_special(data, n);
  int all_ff = n == 8;
  for (size_t k = 0; all_ff && k < 7; k++) all_ff = data[k] == 0xFF;
  CHECK(special == (all_ff && (data[7] == CM_ENTER || data[7] == CM_EXIT || data[7] == CM_SET_ZERO ||
                               data[7] == CM_CLEAR_ERROR) ? data[7] : 0));
  if (special) {
    cm_pack_special(again, (uint8_t)special);
    CHECK(memcmp(again, data, 8) == 0);
  }

  int rc = cm_unpack_command(r, data, n, &c);
  CHECK(rc == (n != 8 ? CM_ELEN : !valid ? CM_EVALUE : special ? CM_EKIND : CM_OK));
  if (rc == CM_OK) {
    const cm_real v[5] = {c.p, c.v, c.kp, c.kd, c.t};
    uint32_t a[5], b[5];
    unsigned clamped = 99;
    for (int k = 0; k < 5; k++) check_inside(v[k], field_of(r, k));
    CHECK(cm_pack_command(r, &c, again, &clamped) == CM_OK);
    command_codes(data, a);
    command_codes(again, b);
    for (int k = 0; k < 5; k++) CHECK(within_one(a[k], b[k]));
    CHECK(clamped == 0 || valid);
  }

  rc = cm_unpack_mit_reply(r, data, n, &y);
  CHECK(rc == (n != 6 && n != 7 ? CM_ELEN : !valid ? CM_EVALUE : CM_OK));
  if (rc == CM_OK) {
    check_reply(r, &y);
    CHECK(y.id == data[0] && y.voltage == (n == 7 ? data[6] : 0) && y.status == 0);
    CHECK(cm_pack_mit_reply(r, &y, again) == CM_OK);
    check_repacked(data, again, 6);
  }

  rc = cm_unpack_damiao_feedback(r, data, n, &y);
  CHECK(rc == (n != 8 ? CM_ELEN : !valid ? CM_EVALUE : CM_OK));
  if (rc == CM_OK) {
    check_reply(r, &y);
    CHECK(y.id == (data[0] & 0xF) && y.status == data[0] >> 4 && y.status <= 0xF);
    CHECK(y.temperature == (int8_t)data[6] && y.temperature2 == (int8_t)data[7]);
    CHECK(cm_pack_damiao_feedback(r, &y, again) == CM_OK);
    check_repacked(data, again, 8);
  }

  rc = cm_unpack_cubemars_reply(r, data, n, &y);
  CHECK(rc == (n != 8 ? CM_ELEN : !valid ? CM_EVALUE : CM_OK));
  if (rc == CM_OK) {
    check_reply(r, &y);
    CHECK(y.id == data[0] && y.status == data[7] && y.temperature == (int8_t)data[6]);
    CHECK(cm_pack_cubemars_reply(r, &y, again) == CM_OK);
    check_repacked(data, again, 8);
  }

  rc = cm_unpack_register(data, n, &g);
  if (n != 4 && n != 8) {
    CHECK(rc == CM_ELEN);
  } else {
    int known = data[2] == CM_REG_READ || data[2] == CM_REG_WRITE || data[2] == CM_REG_STORE ||
                data[2] == CM_REG_REFRESH;
    CHECK(rc == (known ? CM_OK : CM_EKIND));
    if (rc == CM_OK) {
      cm_pack_register(&g, again);
      CHECK(memcmp(again, data, n) == 0);
      if (n == 4) CHECK(g.value == 0 && again[4] == 0 && again[5] == 0 && again[6] == 0 && again[7] == 0);
    }
  }
}

static void encode(const cm_ranges* r, input* in) {
  int valid = ranges_valid(r);
  cm_command c;
  c.p = take_real(in);
  c.v = take_real(in);
  c.kp = take_real(in);
  c.kd = take_real(in);
  c.t = take_real(in);
  const cm_real v[5] = {c.p, c.v, c.kp, c.kd, c.t};
  int all_finite = 1;
  for (int k = 0; k < 5; k++) all_finite &= finite(v[k]);
  uint8_t out[8];
  unsigned clamped = 99;
  int rc = cm_pack_command(r, &c, out, &clamped);
  CHECK(rc == (valid && all_finite ? CM_OK : CM_EVALUE));
  if (rc == CM_OK) {
    cm_command back;
    CHECK(cm_unpack_command(r, out, 8, &back) == CM_OK || cm_special(out, 8));
    if (!cm_special(out, 8)) {
      const cm_real b[5] = {back.p, back.v, back.kp, back.kd, back.t};
      for (int k = 0; k < 5; k++) {
        field f = field_of(r, k);
        check_round_trip(v[k], b[k], f);
        CHECK(!!(clamped & (1u << k)) == (v[k] < f.lo || v[k] > f.hi));
      }
    }
  }

  // a reply's state (p, v, t) and its bytes, through every dialect's encoder and decoder
  cm_reply y = {0};
  y.p = c.p;
  y.v = c.v;
  y.t = c.t;
  y.id = take(in);
  y.status = take(in);
  y.temperature = (int8_t)take(in);
  y.temperature2 = (int8_t)take(in);
  int state_finite = finite(y.p) && finite(y.v) && finite(y.t);
  for (int kind = 0; kind < 3; kind++) {
    cm_reply back;
    uint8_t frame[8];
    size_t n = kind == 0 ? 6 : 8;
    rc = kind == 0 ? cm_pack_mit_reply(r, &y, frame)
       : kind == 1 ? cm_pack_damiao_feedback(r, &y, frame) : cm_pack_cubemars_reply(r, &y, frame);
    CHECK(rc == (valid && state_finite ? CM_OK : CM_EVALUE));
    if (rc != CM_OK) continue;
    rc = kind == 0 ? cm_unpack_mit_reply(r, frame, n, &back)
       : kind == 1 ? cm_unpack_damiao_feedback(r, frame, n, &back) : cm_unpack_cubemars_reply(r, frame, n, &back);
    CHECK(rc == CM_OK);
    check_round_trip(y.p, back.p, field_of(r, 0));
    check_round_trip(y.v, back.v, field_of(r, 1));
    check_round_trip(y.t, back.t, field_of(r, 4));
    if (kind == 1) {
      CHECK(back.id == (y.id & 0xF) && back.status == (y.status & 0xF));
      CHECK(back.temperature == y.temperature && back.temperature2 == y.temperature2);
    } else {
      CHECK(back.id == y.id);
      if (kind == 2) CHECK(back.status == y.status && back.temperature == y.temperature);
    }
  }
}

int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  input in = {data, size};
  uint8_t op = take(&in);
  cm_ranges r;
  r.p_max = take_real(&in);
  r.v_max = take_real(&in);
  r.t_max = take_real(&in);
  r.kp_max = take_real(&in);
  r.kd_max = take_real(&in);
  if (op & 1) {
    encode(&r, &in);
  } else {
    uint8_t* frame = malloc(in.n ? in.n : 1);   // exactly the frame's size
    if (in.n) memcpy(frame, in.p, in.n);
    decode(&r, frame, in.n);
    free(frame);
  }
  return 0;
}
