// canmotor_check.c: the CAN motor frame codec (hal/can/c) in the Cortex-M4F build, in float.
//
// Links every function of the codec into the image, so check-mcu.sh sees its size and that it
// needs no double-precision helper, and runs it once under QEMU on the single-precision FPU:
// the packing must be the motors' own float_to_uint computed in float32 (the vectors below are
// values where float32 and double give different codes in every field; tests/test_can_frames.py
// checks the table against its float32 reference), a value out of range clamps, NaN is refused,
// replies, special and register frames decode.
#include "canmotor.h"

// a DM-J4340's MIT ranges (the vendor's defaults): p 12.5 rad, v 8 rad/s, t 28 N m, kp 500, kd 5
static const cm_ranges cm_j4340 = {CM_R(12.5), CM_R(8.0), CM_R(28.0), CM_R(500.0), CM_R(5.0)};

typedef struct {
  cm_command command;
  uint8_t bytes[8];
  unsigned clamped;
} cm_vector;

// BEGIN canmotor vectors (parsed by tests/test_can_frames.py)
static const cm_vector cm_vectors[] = {
  {{CM_R(7.014), CM_R(4.3663), CM_R(309.5238), CM_R(2.1221), CM_R(13.8188)},
   {0xC7, 0xD2, 0xC5, 0xD9, 0xE7, 0x6C, 0xAB, 0xF2}, 0},
  {{CM_R(100.0), CM_R(-100.0), CM_R(-5.0), CM_R(10.0), CM_R(1e30)},
   {0xFF, 0xFF, 0x00, 0x00, 0x00, 0xFF, 0xFF, 0xFF}, 31},
};
// END canmotor vectors

static int same(const uint8_t* a, const uint8_t* b, int n) {
  for (int k = 0; k < n; k++)
    if (a[k] != b[k]) return 0;
  return 1;
}

static int near(cm_real a, cm_real b, cm_real tolerance) {
  return a - b <= tolerance && b - a <= tolerance;
}

// 0, or the number of the first check that failed
int canmotor_check(void) {
  uint8_t out[8];
  unsigned clamped;
  cm_command back;
  cm_reply y;
  cm_register g;
  const unsigned n = sizeof cm_vectors / sizeof cm_vectors[0];
  for (unsigned k = 0; k < n; k++) {
    if (cm_pack_command(&cm_j4340, &cm_vectors[k].command, out, &clamped) != CM_OK) return 1;
    if (!same(out, cm_vectors[k].bytes, 8) || clamped != cm_vectors[k].clamped) return 2;
    if (cm_unpack_command(&cm_j4340, out, 8, &back) != CM_OK) return 3;
    if (k == 0 && !near(back.t, cm_vectors[0].command.t, CM_R(56.0) / CM_R(4095.0))) return 3;
  }
  cm_command bad = cm_vectors[0].command;
  bad.kd = CM_R(0.0) / CM_R(0.0) + bad.kd;   // NaN without <math.h>
  if (cm_pack_command(&cm_j4340, &bad, out, &clamped) != CM_EVALUE) return 4;

  // Damiao's feedback layout: motor 3 enabled, p code 0x8000, v 0x800, t 0x7FF, 35 and 41 degC
  static const uint8_t feedback[8] = {0x13, 0x80, 0x00, 0x80, 0x07, 0xFF, 35, 41};
  if (cm_unpack_damiao_feedback(&cm_j4340, feedback, 8, &y) != CM_OK) return 5;
  if (y.id != 3 || y.status != 1 || y.temperature != 35 || y.temperature2 != 41) return 5;
  if (!near(y.p, CM_R(0.0), CM_R(25.0) / CM_R(65535.0)) || !near(y.t, CM_R(0.0), CM_R(56.0) / CM_R(4095.0)))
    return 5;
  if (cm_pack_damiao_feedback(&cm_j4340, &y, out) != CM_OK || out[0] != 0x13 || out[6] != 35) return 5;
  if (cm_pack_mit_reply(&cm_j4340, &y, out) != CM_OK || cm_unpack_mit_reply(&cm_j4340, out, 6, &y) != CM_OK)
    return 6;
  if (cm_pack_cubemars_reply(&cm_j4340, &y, out) != CM_OK ||
      cm_unpack_cubemars_reply(&cm_j4340, out, 8, &y) != CM_OK || cm_unpack_mit_reply(&cm_j4340, out, 5, &y) != CM_ELEN)
    return 6;

  cm_pack_special(out, CM_ENTER);
  if (cm_special(out, 8) != CM_ENTER || cm_unpack_command(&cm_j4340, out, 8, &back) != CM_EKIND) return 7;
  const cm_register timeout = {0x105, CM_REG_WRITE, 9, 2000};
  cm_pack_register(&timeout, out);
  if (cm_unpack_register(out, 8, &g) != CM_OK || g.can_id != 0x105 || g.rid != 9 || g.value != 2000) return 8;
  return 0;
}
