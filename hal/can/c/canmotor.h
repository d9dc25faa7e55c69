// canmotor.h: frame codec of MIT-style CAN motors for the firmware and the host.
//
// Dialects: `mit` (Ben Katz's mini-cheetah motorcontrol firmware), `damiao` (DM-J43xx in MIT
// mode, with its register frames on 0x7FF) and `cubemars` (AK series, MIT firmware). A command is
// one 8-byte frame, big-endian bit fields:
//
//   byte  0        1       2        3                  4        5        6                  7
//         p[15:8]  p[7:0]  v[11:4]  v[3:0]<<4|kp[11:8] kp[7:0]  kd[11:4] kd[3:0]<<4|t[11:8] t[7:0]
//
// Each field is x -> (unsigned)((x - min) * (2^bits - 1) / (max - min)), truncating, as the
// firmware's float_to_uint; x is clamped into [min, max] first so it never wraps. Decoding is
// u * (max - min) / (2^bits - 1) + min, so a symmetric range never decodes to exactly 0.
//
// One source, two precisions, chosen as the core's (firmware/core/include/sd_config.h) by the
// same switch: cm_real is double by default (the host: with contraction off the Python codec
// hal/can/frames.py gives the same bytes) and float with -DSD_SINGLE (the firmware on a
// single-precision FPU: float_to_uint/uint_to_float computed in float32, as the motors' own
// firmware computes them). tests/test_can_frames.py checks each build against its reference.
// No heap, no stdio, no libm; every decoder takes (data, len) of one frame kind and returns 0 or
// a negative error, so a fuzzer calls it as is.
#ifndef CANMOTOR_H
#define CANMOTOR_H

#include <stddef.h>
#include <stdint.h>

#ifdef SD_SINGLE
typedef float cm_real;
#define CM_R(x) ((float)(x))
#else
typedef double cm_real;
#define CM_R(x) ((double)(x))
#endif

// The ranges the codec accepts: every range end (p_max, v_max, t_max, kp_max, kd_max) within
// [CM_RANGE_MIN, CM_RANGE_MAX]. Wide enough for any motor (vendors' p_max 12.5 to 95.5 rad, kp_max
// 500), narrow enough that no step of the conversions overflows or sinks into denormals in either
// precision: past 1e6 a range's span times 65535 leaves float's range near 1e38 / 65535 far
// behind, but a span near DBL_MAX (or FLT_MAX) turns (x - min) / span into inf / inf.
#define CM_RANGE_MIN CM_R(1e-6)
#define CM_RANGE_MAX CM_R(1e6)

enum {
  CM_OK = 0,
  CM_ELEN = -1,     // the frame has the wrong length for its kind
  CM_EVALUE = -2,   // a non-finite value, or a range outside [CM_RANGE_MIN, CM_RANGE_MAX]
  CM_EKIND = -3     // the bytes are not a frame of this kind
};

// the special frames: FF x7 then the code, sent to the command id
enum {
  CM_ENTER = 0xFC,       // enter motor mode (Damiao: enable)
  CM_EXIT = 0xFD,        // exit motor mode (disable)
  CM_SET_ZERO = 0xFE,    // the present position becomes zero
  CM_CLEAR_ERROR = 0xFB  // Damiao: clear a latched fault
};

// Damiao register access on CM_DAMIAO_REGISTER_ID
enum {
  CM_DAMIAO_REGISTER_ID = 0x7FF,
  CM_REG_READ = 0x33,
  CM_REG_WRITE = 0x55,
  CM_REG_STORE = 0xAA,
  CM_REG_REFRESH = 0xCC
};

// which command field was clamped into its range (cm_pack_command's *clamped)
enum { CM_CLAMP_P = 1, CM_CLAMP_V = 2, CM_CLAMP_KP = 4, CM_CLAMP_KD = 8, CM_CLAMP_T = 16 };

typedef struct {
  cm_real p_max;       // rad: p in [-p_max, p_max]
  cm_real v_max;       // rad/s
  cm_real t_max;       // N m
  cm_real kp_max;      // N m / rad: kp in [0, kp_max]
  cm_real kd_max;      // N m s / rad
} cm_ranges;

typedef struct {
  cm_real p, v, kp, kd, t;
} cm_command;

typedef struct {
  uint8_t id;          // the motor's id as it reports it (Damiao: the low nibble of CAN_ID)
  uint8_t status;      // Damiao: the status nibble; CubeMars: the error code; mit: 0
  cm_real p, v, t;     // rad, rad/s, N m (CubeMars: the current field over +-t_max)
  int8_t temperature;  // degC: Damiao MOS, CubeMars motor; mit: 0
  int8_t temperature2; // degC: Damiao coil; else 0
  uint8_t voltage;     // mit 7-byte reply: the bus voltage byte; else 0
} cm_reply;

typedef struct {
  uint16_t can_id;     // the motor's command id
  uint8_t cmd;         // CM_REG_READ, CM_REG_WRITE, ...
  uint8_t rid;         // register number
  uint32_t value;      // little-endian bytes 4..7 (a float register's IEEE bits)
} cm_register;

// Field conversions of the firmware (float_to_uint after clamping, uint_to_float), bits 1..16.
uint32_t cm_to_uint(cm_real x, cm_real lo, cm_real hi, unsigned bits);
cm_real cm_to_float(uint32_t u, cm_real lo, cm_real hi, unsigned bits);

// A command frame. *clamped (may be NULL) gets the CM_CLAMP_* bits of the fields clamped.
int cm_pack_command(const cm_ranges* r, const cm_command* c, uint8_t out[8], unsigned* clamped);
// A command frame decoded (what a motor does with it); CM_EKIND for a special frame.
int cm_unpack_command(const cm_ranges* r, const uint8_t* data, size_t len, cm_command* c);

// A special frame; cm_special returns its code, or 0 if the 8 bytes are not one.
void cm_pack_special(uint8_t out[8], uint8_t code);
int cm_special(const uint8_t* data, size_t len);

// mit reply: [id][p16][v12|t12], 6 bytes, or 7 with a voltage byte.
int cm_pack_mit_reply(const cm_ranges* r, const cm_reply* y, uint8_t out[6]);
int cm_unpack_mit_reply(const cm_ranges* r, const uint8_t* data, size_t len, cm_reply* y);

// Damiao feedback: [status<<4|id&F][p16][v12|t12][T_mos][T_coil], 8 bytes.
int cm_pack_damiao_feedback(const cm_ranges* r, const cm_reply* y, uint8_t out[8]);
int cm_unpack_damiao_feedback(const cm_ranges* r, const uint8_t* data, size_t len, cm_reply* y);

// CubeMars reply: [id][p16][v12|i12][temperature][error], 8 bytes.
int cm_pack_cubemars_reply(const cm_ranges* r, const cm_reply* y, uint8_t out[8]);
int cm_unpack_cubemars_reply(const cm_ranges* r, const uint8_t* data, size_t len, cm_reply* y);

// Damiao register frame: [id_lo][id_hi][cmd][rid][value LE x4], 8 bytes, both ways.
void cm_pack_register(const cm_register* g, uint8_t out[8]);
int cm_unpack_register(const uint8_t* data, size_t len, cm_register* g);

#endif
