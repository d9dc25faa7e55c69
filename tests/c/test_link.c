// test_link.c: the host link (firmware/link/link.h): frames against the protocol document's bytes,
// every message packed and unpacked, the decoder on garbage, corruption, loss, too long and other
// versions, the telemetry's fixed point, the controller's retransmit rule, and a robot loaded over
// the link accepted or refused by the core's checks with the reason.
#include <stdio.h>
#include <string.h>

#include "dxl.h"
#include "fixtures.h"
#include "harness.h"
#include "link.h"

//---------------------------------- helpers ------------------------------------------------------

static size_t hex(const char* text, uint8_t* out) {
  size_t n = 0;
  unsigned v;
  int used;
  while (sscanf(text, " %2x%n", &v, &used) == 1) {
    out[n++] = (uint8_t)v;
    text += used;
  }
  return n;
}

static void expect_hex(const uint8_t* got, size_t n, const char* text, const char* reason) {
  uint8_t want[LINK_MAX_WIRE * 2];
  size_t m = hex(text, want), i = 0;
  EXPECT_INT(n, m, reason);
  while (i < n && i < m && got[i] == want[i]) i++;
  EXPECT_INT(i, m, reason);   // measured = index of the first differing byte
}

static uint32_t next_random(uint32_t* s) {
  *s ^= *s << 13;
  *s ^= *s >> 17;
  *s ^= *s << 5;
  return *s;
}

// feed bytes, collect the verdicts that are not LINK_MORE (at most max)
static int feed_all(link_decoder* d, const uint8_t* p, size_t n, int* codes, int max) {
  int k = 0;
  for (size_t i = 0; i < n; i++) {
    int c = link_decoder_feed(d, p[i]);
    if (c != LINK_MORE && k < max) codes[k++] = c;
  }
  return k;
}

//---------------------------------- framing ------------------------------------------------------

// docs/host-link.md's examples, the Python codec's bytes too (tests/test_host_link.py)
static void frames_are_the_documents_bytes(void) {
  uint8_t out[LINK_MAX_WIRE], p[LINK_MAX_PAYLOAD];
  link_hello hello = {0x1234};
  size_t n = link_pack_hello(p, sizeof p, &hello);
  size_t w = link_frame(out, sizeof out, 0, 0, LINK_HELLO, p, n);
  expect_hex(out, w, "02 01 01 03 01 02 03 34 12 02 11 00", "HELLO, seq 0, nonce 0x1234");
  link_command cmd = {LINK_CMD_PLAY, 0};
  n = link_pack_command(p, sizeof p, &cmd);
  w = link_frame(out, sizeof out, 5, 1, LINK_COMMAND, p, n);
  expect_hex(out, w, "06 01 05 01 07 05 02 02 01 01 01 03 86 D0 00", "COMMAND PLAY, seq 5, ack 1");
}

static void a_frame_has_no_zero_but_its_end(void) {
  uint8_t out[LINK_MAX_WIRE], p[LINK_MAX_PAYLOAD];
  uint32_t s = 7;
  int zeros = 0, ends = 0;
  for (int trial = 0; trial < 200; trial++) {
    size_t n = next_random(&s) % (LINK_MAX_PAYLOAD + 1);
    for (size_t i = 0; i < n; i++) p[i] = (uint8_t)(next_random(&s) % 3 ? 0 : next_random(&s));
    size_t w = link_frame(out, sizeof out, (uint8_t)trial, 3, LINK_KNOTS, p, n);
    EXPECT_INT(w, n + LINK_HEADER + LINK_CRC + 2, "COBS adds one byte to a frame under 254, the delimiter one");
    for (size_t i = 0; i + 1 < w; i++) zeros += out[i] == 0;
    ends += out[w - 1] == 0;
    link_decoder d;
    link_decoder_reset(&d);
    int codes[4];
    int k = feed_all(&d, out, w, codes, 4);
    EXPECT_INT(k == 1 && codes[0] == LINK_FRAME, 1, "a frame decodes once, good");
    EXPECT_INT(d.len, n, "its length");
    EXPECT_INT(n == 0 || memcmp(d.payload, p, n) == 0, 1, "its payload");
    EXPECT_INT(d.seq, (uint8_t)trial, "its seq");
  }
  EXPECT_INT(zeros, 0, "00 only ends a frame");
  EXPECT_INT(ends, 200, "every frame ends with 00");
  EXPECT_INT(link_frame(out, sizeof out, 0, 0, LINK_KNOTS, p, LINK_MAX_PAYLOAD + 1), 0,
             "a payload over LINK_MAX_PAYLOAD is refused");
  EXPECT_INT(link_frame(out, 20, 0, 0, LINK_KNOTS, p, 40), 0, "a frame over cap is refused");
}

static void decoder_survives_garbage_corruption_and_loss(void) {
  uint8_t a[LINK_MAX_WIRE], b[LINK_MAX_WIRE], p[64], stream[4 * LINK_MAX_WIRE];
  for (int i = 0; i < 64; i++) p[i] = (uint8_t)(i * 37);
  size_t na = link_frame(a, sizeof a, 1, 0, LINK_KNOTS, p, 64);
  size_t nb = link_frame(b, sizeof b, 2, 0, LINK_KNOTS, p, 10);
  link_decoder d;
  int codes[8], k;

  // garbage before: it ends at the first 00 as a bad frame, the next frame is good
  static const uint8_t junk[] = {0x55, 0xAA, 0x13};
  memcpy(stream, junk, 3);
  memcpy(stream + 3, a, na);
  link_decoder_reset(&d);
  k = feed_all(&d, stream, 3 + na, codes, 8);
  EXPECT_INT(k, 1, "joined mid-frame: the garbage and the frame are one run to the first 00");
  EXPECT_INT(codes[0] != LINK_FRAME, 1, "a frame with garbage in front is not taken");
  k = feed_all(&d, b, nb, codes, 8);
  EXPECT_INT(k == 1 && codes[0] == LINK_FRAME && d.seq == 2, 1, "the next frame is good");
  // a leading 00 resynchronises at once
  link_decoder_reset(&d);
  stream[3] = 0;
  memcpy(stream + 4, a, na);
  k = feed_all(&d, stream, 4 + na, codes, 8);
  EXPECT_INT(k == 2 && codes[1] == LINK_FRAME, 1, "a 00 before a frame cuts the garbage off");

  // every corrupt byte (each bit) or lost byte of frame a, then frames b and c: a is never taken,
  // c always is, b too unless the byte was a's delimiter (a and b then run together)
  uint8_t c[LINK_MAX_WIRE];
  size_t nc = link_frame(c, sizeof c, 3, 0, LINK_KNOTS, p, 3);
  int wrong = 0, b_lost = 0, c_lost = 0, trials = 0;
  for (size_t i = 0; i < na; i++) {
    for (int bit = 0; bit < 9; bit++) {          // bit 8: the byte is lost
      size_t m = 0;
      for (size_t j = 0; j < na; j++) {
        if (j != i) stream[m++] = a[j];
        else if (bit < 8) stream[m++] = (uint8_t)(a[j] ^ (1u << bit));
      }
      memcpy(stream + m, b, nb);
      memcpy(stream + m + nb, c, nc);
      link_decoder_reset(&d);
      int seen_a = 0, seen_b = 0, seen_c = 0;
      for (size_t j = 0; j < m + nb + nc; j++) {
        if (link_decoder_feed(&d, stream[j]) != LINK_FRAME) continue;
        seen_a += d.seq == 1;
        seen_b += d.seq == 2;
        seen_c += d.seq == 3;
      }
      trials++;
      wrong += seen_a;
      b_lost += !seen_b && i != na - 1;
      c_lost += !seen_c;
    }
  }
  EXPECT_INT(trials, 9 * (int)na, "every byte, every bit, and lost");
  EXPECT_INT(wrong, 0, "no corrupt or shortened frame is taken");
  EXPECT_INT(b_lost, 0, "the next frame is taken unless the 00 was hit");
  EXPECT_INT(c_lost, 0, "the frame after that always is");
}

static void decoder_refuses_too_long_short_and_other_versions(void) {
  link_decoder d;
  link_decoder_reset(&d);
  int codes[4], k;
  uint8_t big[LINK_MAX_RAW + 20];
  memset(big, 0x11, sizeof big);
  big[sizeof big - 1] = 0;
  k = feed_all(&d, big, sizeof big, codes, 4);
  EXPECT_INT(k == 1 && codes[0] == LINK_BAD_TOO_LONG, 1, "over LINK_MAX_RAW before the 00");
  static const uint8_t shorty[] = {0x03, 0x01, 0x02, 0x00};
  k = feed_all(&d, shorty, sizeof shorty, codes, 4);
  EXPECT_INT(k == 1 && codes[0] == LINK_BAD_SHORT, 1, "under the header and CRC");
  static const uint8_t cut[] = {0x09, 0x01, 0x02, 0x00};
  k = feed_all(&d, cut, sizeof cut, codes, 4);
  EXPECT_INT(k == 1 && codes[0] == LINK_BAD_SHORT, 1, "a COBS block cut by the 00");
  static const uint8_t empties[] = {0, 0, 0};
  EXPECT_INT(feed_all(&d, empties, 3, codes, 4), 0, "00 00: nothing");

  // version 2's hello: good CRC, refused with its version and seq readable
  uint8_t raw[LINK_MAX_RAW], out[LINK_MAX_WIRE];
  uint8_t head[] = {2, 9, 0, LINK_HELLO, 2, 0, 0x34, 0x12};
  memcpy(raw, head, 8);
  uint16_t crc = dxl_crc(0, raw, 8);
  raw[8] = (uint8_t)(crc >> 8);
  raw[9] = (uint8_t)crc;
  // COBS by hand: no zero but at 2 and 5 ...
  size_t w = 0, at = 0;
  out[w++] = 0;
  for (size_t i = 0; i < 10; i++) {
    if (raw[i] == 0) {
      out[at] = (uint8_t)(w - at);
      at = w;
      out[w++] = 0;
    } else {
      out[w++] = raw[i];
    }
  }
  out[at] = (uint8_t)(w - at);
  out[w++] = 0;
  k = feed_all(&d, out, w, codes, 4);
  EXPECT_INT(k == 1 && codes[0] == LINK_BAD_VERSION, 1, "another version is refused as such");
  EXPECT_INT(d.version * 1000 + d.seq, 2009, "with its version and seq, for the reply");
}

// long random streams of frames with random corruption: no corrupt frame is ever taken
static void random_streams_never_take_a_corrupt_frame(void) {
  uint32_t s = 12345;
  link_decoder d;
  link_decoder_reset(&d);
  uint8_t out[LINK_MAX_WIRE], p[LINK_MAX_PAYLOAD];
  long sent = 0, taken = 0, wrong = 0, intact = 0;
  for (int f = 0; f < 20000; f++) {
    size_t n = next_random(&s) % 40;
    for (size_t i = 0; i < n; i++) p[i] = (uint8_t)next_random(&s);
    size_t w = link_frame(out, sizeof out, (uint8_t)f, 0, LINK_KNOTS, p, n);
    int damaged = 0;
    for (size_t i = 0; i < w; i++) {
      if (next_random(&s) % 500 == 0) {
        out[i] ^= (uint8_t)(1 + next_random(&s) % 255);
        damaged = 1;
      }
    }
    sent++;
    intact += !damaged;
    for (size_t i = 0; i < w; i++) {
      if (link_decoder_feed(&d, out[i]) == LINK_FRAME) {
        taken++;
        wrong += d.seq != (uint8_t)f || d.len != n || (n && memcmp(d.payload, p, n) != 0);
      }
    }
  }
  EXPECT_INT(wrong, 0, "every frame taken is a frame sent, byte for byte");
  EXPECT_GE((double)taken, (double)intact * 0.98, "nearly every intact frame is taken (not those after a lost 00)");
  EXPECT_LE((double)taken, (double)sent, "no frame is made up");
}

//---------------------------------- messages -----------------------------------------------------

// packed again after an unpack: the same bytes
static int repacks(const uint8_t* p, size_t n, size_t n2, const uint8_t* q) {
  return n > 0 && n2 == n && memcmp(p, q, n) == 0;
}

static void messages_round_trip(void) {
  uint8_t p[LINK_MAX_PAYLOAD], q[LINK_MAX_PAYLOAD];
  link_hello_reply hr = {0xBEEF, LINK_VERSION, 1, 2, 3, "netduino", 4, 16, 8, 64, LINK_MAX_PAYLOAD,
                         LINK_WINDOW, 6, LINK_LOADED};
  link_hello_reply hr2;
  size_t n = link_pack_hello_reply(p, sizeof p, &hr);
  EXPECT_INT(n, 27, "HELLO_REPLY is 27 bytes");
  EXPECT_INT(link_unpack_hello_reply(p, n, &hr2), LINK_OK, "it unpacks");
  EXPECT_INT(repacks(p, n, link_pack_hello_reply(q, sizeof q, &hr2), q), 1, "every field back");
  EXPECT_INT(hr2.nonce + hr2.knot_slots + hr2.board[7], 0xBEEF + 64 + 'o', "fields in place");
  EXPECT_INT(link_unpack_hello_reply(p, n - 1, &hr2), LINK_E_PAYLOAD, "one byte short");

  link_robot_head h = {3, 6, 0, SD_MODE_FEEDFORWARD_PD, 1, 3, LINK_REACT_HOLD, 10, 100, 1000,
                       {0, 0, SD_R(-9.81)}, SD_R(0.05), SD_R(0.1), SD_R(0.05), SD_R(0.95),
                       SD_R(0.2), SD_R(1.0)};
  link_robot_head h2;
  n = link_pack_robot_head(p, sizeof p, &h);
  EXPECT_INT(n, 51, "LOAD_ROBOT is 51 bytes");
  EXPECT_INT(link_unpack_robot_head(p, n, &h2), LINK_OK, "it unpacks");
  EXPECT_INT(repacks(p, n, link_pack_robot_head(q, sizeof q, &h2), q), 1, "every field back");
  EXPECT_NEAR(h2.gravity[2], -9.81, 1e-6, "gravity in place (float32 of -9.81)");
  EXPECT_INT(h2.period_us + h2.reaction, 1000 + LINK_REACT_HOLD, "period and reaction in place");

  link_body b = {2, 1, 3, 0, {SD_R(0.5), 0, SD_R(0.25)}, {1, 0, 0, 0, 1, 0, 0, 0, 1}, SD_R(1.5),
                 {0, SD_R(0.125), 0}, {SD_R(0.01), SD_R(0.02), SD_R(0.03), 0, 0, 0}};
  link_body b2;
  n = link_pack_body(p, sizeof p, &b);
  EXPECT_INT(n, 92, "LOAD_BODY is 92 bytes");
  EXPECT_INT(link_unpack_body(p, n, &b2), LINK_OK, "it unpacks");
  EXPECT_INT(repacks(p, n, link_pack_body(q, sizeof q, &b2), q), 1, "every field back");
  EXPECT_NEAR(b2.com[1] + b2.mass, 0.125 + 1.5, 0, "com and mass in place (exact in float32)");
  EXPECT_NEAR(b2.inertia[2], 0.03, 1e-9, "inertia in place");
  b.parent = -1;
  n = link_pack_body(p, sizeof p, &b);
  link_unpack_body(p, n, &b2);
  EXPECT_INT(b2.parent, -1, "parent -1, the base, is a signed byte");

  link_joint j, j2;
  memset(&j, 0, sizeof j);
  j.index = 5;
  j.bus = LINK_BUS_CAN;
  j.id = 0x21;
  j.model_number = 1020;
  j.dof_rot[0] = j.dof_rot[4] = j.dof_rot[8] = 1;
  j.zero_offset = SD_R(0.5);
  j.observer_lowpass = SD_R(30.0);
  j.armature = SD_R(0.01);
  j.direction = -1;
  j.kp = SD_R(12.5);
  j.contact_threshold = SD_R(0.75);
  j.dialect = LINK_DIALECT_CUBEMARS;
  j.reply_id = 0x7FF;
  j.mit_range[4] = SD_R(5.0);
  n = link_pack_joint(p, sizeof p, &j);
  EXPECT_INT(n, 152, "LOAD_JOINT is 152 bytes");
  EXPECT_INT(link_unpack_joint(p, n, &j2), LINK_OK, "it unpacks");
  EXPECT_INT(repacks(p, n, link_pack_joint(q, sizeof q, &j2), q), 1, "every field back");
  EXPECT_NEAR(j2.kp + j2.contact_threshold + j2.direction + j2.model_number, 12.5 + 0.75 - 1 + 1020, 0,
              "fields in place");
  EXPECT_INT(p[129] * 100000 + (p[130] | p[131] << 8), 3 * 100000 + 0x7FF, "dialect at 129, reply_id at 130, LE");
  EXPECT_NEAR(j2.mit_range[4] + j2.dialect + j2.reply_id, 5.0 + 3 + 0x7FF, 0, "the CAN fields back");

  link_command c = {LINK_CMD_HOME, 2500}, c2;
  n = link_pack_command(p, sizeof p, &c);
  EXPECT_INT(n, 5, "COMMAND is 5 bytes");
  link_unpack_command(p, n, &c2);
  EXPECT_INT(c2.command * 100000 + (long)c2.arg, LINK_CMD_HOME * 100000 + 2500, "command and arg back");

  link_result r = {200, LINK_COMMIT, LINK_STAGE_MODEL, SD_ERR_MASS, -1, 31}, r2;
  n = link_pack_result(p, sizeof p, &r);
  EXPECT_INT(n, 8, "RESULT is 8 bytes");
  link_unpack_result(p, n, &r2);
  EXPECT_INT(repacks(p, n, link_pack_result(q, sizeof q, &r2), q), 1, "every field back");
  EXPECT_INT(r2.code * 1000 + r2.index, SD_ERR_MASS * 1000 - 1, "negative code and index");
  EXPECT_INT(link_pack_result(p, 7, &r), 0, "a buffer too small is refused");
}

static void telemetry_is_fixed_point(void) {
  uint8_t p[LINK_MAX_PAYLOAD];
  link_telemetry t, t2;
  memset(&t, 0, sizeof t);
  t.tick = 123456;
  t.work_us = 87;
  t.njoint = 7;
  t.flags = LINK_TM_LIMITED;
  for (int k = 0; k < 7; k++) {
    t.joint[k].q = SD_R(0.1) * (sd_real)k - SD_R(0.3);
    t.joint[k].qd = SD_R(1.7) * (sd_real)k;
    t.joint[k].q_d = t.joint[k].q + SD_R(0.001);
    t.joint[k].tau = SD_R(-0.6) * (sd_real)k;
    t.joint[k].effort = (int16_t)(-100 * k);
    t.joint[k].command = (int16_t)(37 * k);
    t.joint[k].residual = SD_R(0.02);
  }
  size_t n = link_pack_telemetry(p, sizeof p, &t);
  EXPECT_INT(n, 15 + 14 * 7, "7 joints' telemetry: 113 payload bytes");
  EXPECT_INT(n + LINK_HEADER + LINK_CRC + 2, 123, "123 bytes a tick on the wire");
  EXPECT_INT(link_unpack_telemetry(p, n, &t2), LINK_OK, "it unpacks");
  EXPECT_INT(t2.flags, LINK_TM_LIMITED, "no value saturated");
  double worst_q = 0, worst_qd = 0, worst_tau = 0;
  for (int k = 0; k < 7; k++) {
    double e = sd_fabs(t2.joint[k].q - t.joint[k].q);
    worst_q = e > worst_q ? e : worst_q;
    e = sd_fabs(t2.joint[k].qd - t.joint[k].qd);
    worst_qd = e > worst_qd ? e : worst_qd;
    e = sd_fabs(t2.joint[k].tau - t.joint[k].tau);
    worst_tau = e > worst_tau ? e : worst_tau;
    EXPECT_INT(t2.joint[k].command, 37 * k, "the command is exact: servo units");
    EXPECT_INT(t2.joint[k].effort, -100 * k, "the effort is exact: servo units");
  }
  EXPECT_LE(worst_q, 0.5 / 4096 + 1e-7, "q within half an LSB (2^-12 rad)");
  EXPECT_LE(worst_qd, 0.5 / 512 + 1e-6, "qd within half an LSB (2^-9 rad/s)");
  EXPECT_LE(worst_tau, 0.5 / 512 + 1e-6, "tau within half an LSB (2^-9 N m)");

  t.joint[0].q = SD_R(9.0);          // past +8 rad
  t.joint[1].q = (sd_real)NAN;
  t.joint[2].q = SD_R(-0.5) / 4096;  // half an LSB: away from zero
  n = link_pack_telemetry(p, sizeof p, &t);
  link_unpack_telemetry(p, n, &t2);
  EXPECT_INT(t2.flags, LINK_TM_LIMITED | LINK_TM_SATURATED, "a clamped value sets SATURATED");
  EXPECT_NEAR(t2.joint[0].q, 32767.0 / 4096, 0, "clamped to the largest code");
  EXPECT_INT(t2.joint[1].q != t2.joint[1].q, 1, "NaN travels as NaN");
  EXPECT_NEAR(t2.joint[2].q, -1.0 / 4096, 0, "half an LSB rounds away from zero");
  t.njoint = LINK_MAX_TELEMETRY_JOINT + 1;
  EXPECT_INT(link_pack_telemetry(p, sizeof p, &t), 0, "more joints than a frame holds: refused");
}

static void knots_pack_with_and_without_gains(void) {
  uint8_t p[LINK_MAX_PAYLOAD];
  static link_knot k[3], back;
  for (int i = 0; i < 3; i++) {
    k[i].t_us = 1000u * (uint32_t)i;
    for (int d = 0; d < 7; d++) {
      k[i].q[d] = SD_R(0.25) * (sd_real)(i + d);
      k[i].qd[d] = SD_R(-0.5) * (sd_real)d;
      k[i].qdd[d] = SD_R(2.0);
      k[i].kp[d] = SD_R(8.0);
      k[i].kd[d] = SD_R(0.125);
    }
  }
  link_knots m = {40, 7, 2, 0}, m2;
  size_t n = link_pack_knots(p, sizeof p, &m, k);
  EXPECT_INT(n, 7 + 2 * 88, "two knots of 7 dofs: 4 + 84 bytes each");
  EXPECT_INT(link_unpack_knots(p, n, &m2), LINK_OK, "it unpacks");
  EXPECT_INT(m2.first * 100 + m2.count, 4002, "first and count back");
  link_knot_at(p, &m2, 1, &back);
  EXPECT_INT(back.t_us, 1000, "knot 1's time");
  EXPECT_NEAR(back.q[6], 1.75, 0, "knot 1's q");
  EXPECT_NEAR(back.qd[3], -1.5, 0, "knot 1's qd");
  m.flags = LINK_KNOT_GAINS | LINK_KNOT_LAST;
  m.count = 1;
  n = link_pack_knots(p, sizeof p, &m, k + 2);
  EXPECT_INT(n, 7 + 144, "a knot with gains: 4 + 140 bytes");
  link_unpack_knots(p, n, &m2);
  link_knot_at(p, &m2, 0, &back);
  EXPECT_NEAR(back.kd[6], 0.125, 0, "its gains");
  m.count = 2;
  EXPECT_INT(link_pack_knots(p, sizeof p, &m, k), 0, "two knots with gains are over a frame");
  EXPECT_INT(link_unpack_knots(p, n - 1, &m2), LINK_E_PAYLOAD, "a byte short");
  p[5] = 0;
  EXPECT_INT(link_unpack_knots(p, n, &m2), LINK_E_PAYLOAD, "count 0");
}

// a KNOTS payload of count knots of 3 dofs from index first, times 10 ms apart (t0 for the first)
static size_t knots_payload(uint8_t* p, uint32_t first, int count, uint32_t t0, int flags) {
  static link_knot k[8];
  for (int i = 0; i < count; i++) {
    k[i].t_us = t0 + 10000u * (uint32_t)i;
    for (int d = 0; d < 3; d++) k[i].q[d] = (sd_real)(first + (uint32_t)i) + SD_R(0.25) * (sd_real)d;
  }
  link_knots m = {first, 3, (uint8_t)count, (uint8_t)flags};
  return link_pack_knots(p, LINK_MAX_PAYLOAD, &m, k);
}

static void knot_ring_takes_whole_messages_in_order_within_its_slots(void) {
  static link_ring r;
  uint8_t p[LINK_MAX_PAYLOAD];
  link_result res;
  link_ring_reset(&r, 3, 5);
  link_ring_push(&r, p, knots_payload(p, 0, 4, 0, 0), &res);
  EXPECT_INT(res.code * 100 + res.credits, 1, "4 knots taken, 1 slot free");
  link_ring_push(&r, p, knots_payload(p, 4, 2, 40000, 0), &res);
  EXPECT_INT(res.code * 100 + res.credits, LINK_E_FULL * 100 + 1, "2 more do not fit: refused whole");
  EXPECT_INT(r.count, 4, "nothing half taken");
  link_ring_pop(&r);
  link_ring_pop(&r);
  link_ring_push(&r, p, knots_payload(p, 4, 2, 40000, 0), &res);
  EXPECT_INT(res.code * 100 + res.credits, 1, "two played, two taken: across the ring's end");
  EXPECT_NEAR(link_ring_at(&r, 3)->q[1], 5.25, 0, "the 4th held is knot 5 (q = 5 + 0.25)");
  EXPECT_INT(link_ring_at(&r, 0)->t_us, 20000, "the oldest held is knot 2");
  EXPECT_INT(link_ring_at(&r, 4) == NULL, 1, "past the knots held: none");
  link_ring_push(&r, p, knots_payload(p, 7, 1, 90000, 0), &res);
  EXPECT_INT(res.code * 1000 + res.index, LINK_E_KNOT * 1000 + 6, "knot 6 was next: refused, naming 6");
  link_ring_push(&r, p, knots_payload(p, 6, 1, 50000, 0), &res);
  EXPECT_INT(res.code * 1000 + res.index, LINK_E_KNOT * 1000 + 6, "a time not after the last: refused");
  link_ring_pop(&r);
  link_ring_push(&r, p, knots_payload(p, 6, 1, 60000, LINK_KNOT_LAST), &res);
  EXPECT_INT(res.code, LINK_OK, "the motion's last knot");
  link_ring_pop(&r);
  link_ring_push(&r, p, knots_payload(p, 7, 1, 70000, 0), &res);
  EXPECT_INT(res.code, LINK_E_STATE, "nothing after the last knot");
  link_ring_reset(&r, 2, 5);
  link_ring_push(&r, p, knots_payload(p, 0, 1, 0, 0), &res);
  EXPECT_INT(res.code, LINK_E_PAYLOAD, "3 dofs a knot for a robot of 2");
}

// a motion 100 times the ring, topped up as it plays (one knot a tick): every knot once, in order
static void knot_ring_streams_a_motion_longer_than_itself(void) {
  static link_ring r;
  uint8_t p[LINK_MAX_PAYLOAD];
  link_result res;
  link_ring_reset(&r, 3, 8);
  uint32_t sent = 0, played = 0, wrong = 0, refused = 0;
  for (int tick = 0; tick < 1000 && played < 800; tick++) {
    while (sent < 800 && link_ring_free(&r) >= 3) {
      int count = sent + 3 <= 800 ? 3 : (int)(800 - sent);
      link_ring_push(&r, p, knots_payload(p, sent, count, 10000u * sent, sent + (uint32_t)count == 800 ? LINK_KNOT_LAST : 0), &res);
      refused += res.code != LINK_OK;
      sent += (uint32_t)count;
    }
    const link_knot* k = link_ring_at(&r, 0);
    if (k) {
      wrong += k->t_us != 10000u * played;
      link_ring_pop(&r);
      played++;
    }
  }
  EXPECT_INT(played, 800, "800 knots through 8 slots");
  EXPECT_INT(wrong + refused, 0, "each in order, none refused");
  EXPECT_INT(r.ended, 1, "the last knot marked the end");
}

//---------------------------------- the retransmit rule ------------------------------------------

static void server_executes_once_repeats_and_refuses(void) {
  link_server s;
  link_server_reset(&s);
  link_result r;
  EXPECT_INT(link_server_accept(&s, 0, LINK_COMMAND, &r), LINK_REFUSE, "nothing before a HELLO");
  EXPECT_INT(link_server_accept(&s, 250, LINK_HELLO, &r), LINK_EXECUTE, "HELLO at any seq");
  link_result done = {250, LINK_HELLO, 0, 0, -1, 0};
  link_server_done(&s, &done);
  EXPECT_INT(s.expected, 251, "then the next seq");
  int executed = 0;
  for (int i = 0; i < 10; i++) {   // seq 251 .. 255, 0 .. 4: the wrap
    uint8_t seq = (uint8_t)(251 + i);
    if (link_server_accept(&s, seq, LINK_COMMAND, &r) == LINK_EXECUTE) {
      executed++;
      link_result res = {seq, LINK_COMMAND, 0, 0, (int16_t)i, 0};
      link_server_done(&s, &res);
    }
  }
  EXPECT_INT(executed, 10, "in order: each executed, across the wrap");
  EXPECT_INT(s.expected, 5, "E after the wrap");
  EXPECT_INT(link_server_accept(&s, 3, LINK_COMMAND, &r), LINK_REPEAT, "a retransmitted request");
  EXPECT_INT(r.index, 8, "gets its own result again, not executed twice");
  EXPECT_INT(link_server_accept(&s, 3, LINK_KNOTS, &r), LINK_REFUSE, "same seq, another type: not a repeat");
  EXPECT_INT(link_server_accept(&s, (uint8_t)(5 - LINK_WINDOW - 1), LINK_COMMAND, &r), LINK_REFUSE,
             "older than the window: refused");
  EXPECT_INT(link_server_accept(&s, 7, LINK_COMMAND, &r), LINK_REFUSE, "ahead (5, 6 lost): refused");
  EXPECT_INT(r.code * 1000 + r.seq, LINK_E_ORDER * 1000 + 7, "as out of order, naming the seq");
  EXPECT_INT(link_server_accept(&s, 5, LINK_COMMAND, &r), LINK_EXECUTE, "the expected one goes");
}

//---------------------------------- a robot over the link ----------------------------------------

static link_robot g_robot;

// chain3's bodies and joints, as the host would send them; servo j on the Dynamixel bus, id j + 1
static void load_chain3(link_robot* r, link_result* res) {
  static sd_model m;
  sdt_model_chain3(&m);
  link_robot_head h = {(uint8_t)m.nbody, (uint8_t)m.ndof, 0, SD_MODE_FEEDFORWARD_PD, 1, 3,
                       LINK_REACT_HOLD, 10, 100, 1000, {0, 0, SD_R(-9.81)}, SD_R(0.05), SD_R(0.1),
                       SD_R(0.05), SD_R(0.95), SD_R(0.2), SD_R(1.0)};
  link_robot_begin(r, &h, res);
  for (int i = 0; i < m.nbody; i++) {
    link_body b = {(uint8_t)i, (int8_t)m.body_parent[i], (uint8_t)m.body_dofnum[i],
                   (uint8_t)m.body_ball[i], {0}, {0}, m.body_mass[i], {0}, {0}};
    memcpy(b.pos, m.body_pos[i], sizeof b.pos);
    memcpy(b.rot, m.body_rot[i], sizeof b.rot);
    memcpy(b.com, m.body_com[i], sizeof b.com);
    memcpy(b.inertia, m.body_inertia[i], sizeof b.inertia);
    link_robot_body(r, &b, res);
  }
  for (int k = 0; k < m.ndof; k++) {
    link_joint j;
    memset(&j, 0, sizeof j);
    j.index = (uint8_t)k;
    j.bus = LINK_BUS_DYNAMIXEL;
    j.id = (uint8_t)(k + 1);
    j.model_number = 1020;
    memcpy(j.dof_rot, m.dof_rot[k], sizeof j.dof_rot);
    j.armature = m.dof_armature[k];
    j.direction = 1;
    j.gear_ratio = 1;
    j.rad_per_tick = SD_R(0.0015339808);
    j.radps_per_unit = SD_R(0.023980824);
    j.effort_per_unit = SD_R(0.00269);
    j.nm_per_effort = SD_R(1.78);
    j.effort_limit = SD_R(2.0);
    j.q_min = SD_R(-2.5);
    j.q_max = SD_R(2.5);
    j.qd_max = SD_R(6.0);
    j.tau_max = SD_R(3.0);
    j.kp = SD_R(5.0);
    j.kd = SD_R(0.1);
    j.following_error = SD_R(0.15);
    j.observer_gain = SD_R(50.0);
    j.observer_lowpass = SD_R(30.0);
    j.contact_threshold = SD_R(0.5);
    link_robot_joint(r, &j, res);
  }
}

static void commit(link_robot* r, uint8_t buses, link_result* res) {
  link_robot_commit(r, buses, res);
}

static void a_robot_is_checked_by_the_cores_checks(void) {
  link_robot* r = &g_robot;
  link_result res;
  const uint8_t dxl = 1u << LINK_BUS_DYNAMIXEL;
  load_chain3(r, &res);
  commit(r, dxl, &res);
  // chain3 has a 3-dof joint: the controller's check refuses ball joints only
  EXPECT_INT(res.stage * 100 + res.code, 0, "chain3 with sane servos is accepted");
  EXPECT_INT(r->ready, 1, "and ready");
  EXPECT_NEAR(r->model.body_mass[2], r->model.body_mass[2], 0, "set up");

  commit(r, 1u << LINK_BUS_CAN, &res);
  EXPECT_INT(res.stage * 100 + res.code, LINK_STAGE_SERVO * 100 + LINK_SERVO_BUS, "no Dynamixel bus here");
  EXPECT_INT(res.index, 0, "the first joint named");

  load_chain3(r, &res);
  link_body b = {1, 0, 2, 0, {0}, {1, 0, 0, 0, 1, 0, 0, 0, 1}, SD_R(-1.0), {0}, {SD_R(0.01), SD_R(0.01), SD_R(0.01), 0, 0, 0}};
  b.dofnum = (uint8_t)r->model.body_dofnum[1];
  link_robot_body(r, &b, &res);
  commit(r, dxl, &res);
  EXPECT_INT(res.stage * 100 + res.code, LINK_STAGE_MODEL * 100 + SD_ERR_MASS, "a negative mass: sd_model_setup's code");
  EXPECT_INT(res.index, 1, "naming the body");
  EXPECT_INT(r->ready, 0, "not ready");

  load_chain3(r, &res);
  r->joint[2].kp = SD_R(-1.0);
  commit(r, dxl, &res);
  EXPECT_INT(res.stage * 100 + res.code, LINK_STAGE_CONTROL * 100 + SD_CONTROL_ERR_GAIN, "a negative gain: sd_control_check's");

  load_chain3(r, &res);
  r->joint[1].observer_gain = (sd_real)NAN;
  commit(r, dxl, &res);
  EXPECT_INT(res.stage * 100 + res.code, LINK_STAGE_OBSERVER * 100 + SD_OBSERVER_ERR_GAIN, "a NaN observer gain: sd_observer_check's");

  load_chain3(r, &res);
  r->joint[4].id = r->joint[1].id;
  commit(r, dxl, &res);
  EXPECT_INT(res.stage * 100 + res.code + res.index, LINK_STAGE_SERVO * 100 + LINK_SERVO_DUPLICATE + 4, "two joints on one servo");

  load_chain3(r, &res);
  r->joint[3].q_min = SD_R(3.0);
  commit(r, dxl, &res);
  EXPECT_INT(res.stage * 100 + res.code, LINK_STAGE_SERVO * 100 + LINK_SERVO_RANGE, "q_min over q_max");

  load_chain3(r, &res);
  r->head.stall_share = SD_R(1.5);
  commit(r, dxl, &res);
  EXPECT_INT(res.stage * 100 + res.code + res.index, LINK_STAGE_SERVO * 100 + LINK_SERVO_SAFETY - 1, "a stall share over 1: the table");

  load_chain3(r, &res);
  r->joint_seen[5] = 0;
  commit(r, dxl, &res);
  EXPECT_INT(res.code * 100 + res.index, LINK_E_NO_JOINT * 100 + 5, "a joint missing");

  // a CAN motor: its dialect, reply id and MIT ranges (the codec's limits), no Dynamixel unit scales
  const uint8_t both = dxl | 1u << LINK_BUS_CAN;
  const sd_real dm4340[5] = {SD_R(12.5), SD_R(8.0), SD_R(28.0), SD_R(500.0), SD_R(5.0)};
  load_chain3(r, &res);
  link_joint* m = &r->joint[2];
  m->bus = LINK_BUS_CAN, m->dialect = LINK_DIALECT_DAMIAO, m->reply_id = 0x13;
  m->rad_per_tick = m->radps_per_unit = m->effort_per_unit = 0;
  for (int k = 0; k < 5; k++) m->mit_range[k] = dm4340[k];
  commit(r, both, &res);
  EXPECT_INT(res.stage * 100 + res.code, 0, "a Damiao motor beside the Dynamixel servos, both buses: accepted");
  commit(r, dxl, &res);
  EXPECT_INT(res.stage * 100 + res.code + res.index, LINK_STAGE_SERVO * 100 + LINK_SERVO_BUS + 2,
             "a controller without a CAN bus refuses it, naming the joint");
  m->id = r->joint[1].id;
  commit(r, both, &res);
  EXPECT_INT(res.stage * 100 + res.code, 0, "a CAN id equal to a Dynamixel id: another bus, no duplicate");
  m->mit_range[2] = SD_R(2e6);
  commit(r, both, &res);
  EXPECT_INT(res.stage * 100 + res.code + res.index, LINK_STAGE_SERVO * 100 + LINK_SERVO_CAN + 2,
             "t_max over the codec's 1e6: refused");
  m->mit_range[2] = dm4340[2];
  m->reply_id = 0x800;
  commit(r, both, &res);
  EXPECT_INT(res.code, LINK_SERVO_CAN, "a reply id over 11 bits");
  m->reply_id = 0x13, m->dialect = LINK_NDIALECT;
  commit(r, both, &res);
  EXPECT_INT(res.code, LINK_SERVO_CAN, "an unknown dialect");
  m->dialect = LINK_DIALECT_NONE;
  commit(r, both, &res);
  EXPECT_INT(res.code, LINK_SERVO_CAN, "a CAN joint without a dialect");
  r->joint[0].dialect = LINK_DIALECT_MIT, m->dialect = LINK_DIALECT_MIT;
  commit(r, both, &res);
  EXPECT_INT(res.code * 100 + res.index, LINK_SERVO_BUS * 100, "a Dynamixel joint with a CAN dialect");
  r->joint[0].dialect = LINK_DIALECT_NONE;
  m->effort_per_unit = SD_R(0.1);
  commit(r, both, &res);
  EXPECT_INT(res.stage * 100 + res.code, 0, "a CAN motor's unit scales are not looked at");
  r->joint[1].rad_per_tick = 0;
  commit(r, both, &res);
  EXPECT_INT(res.code * 100 + res.index, LINK_SERVO_SCALE * 100 + 1, "a Dynamixel servo's are");

  link_robot_head big = {SD_MAX_BODY > 200 ? 0 : SD_MAX_BODY + 1, 1, 0, 0, 0, 0, 0, 1, 1, 1, {0}, 0, 0, 0, 0, 0, 0};
  link_robot_begin(r, &big, &res);
  EXPECT_INT(res.code, LINK_E_SIZE, "over the compiled sizes (or no body at all)");
  link_robot_body(r, &b, &res);
  EXPECT_INT(res.code, LINK_E_STATE, "a body without a robot begun");
}

const sdt_test sdt_link_tests[] = {
  {"frames_are_the_documents_bytes", frames_are_the_documents_bytes},
  {"a_frame_has_no_zero_but_its_end", a_frame_has_no_zero_but_its_end},
  {"decoder_survives_garbage_corruption_and_loss", decoder_survives_garbage_corruption_and_loss},
  {"decoder_refuses_too_long_short_and_other_versions", decoder_refuses_too_long_short_and_other_versions},
  {"random_streams_never_take_a_corrupt_frame", random_streams_never_take_a_corrupt_frame},
  {"messages_round_trip", messages_round_trip},
  {"telemetry_is_fixed_point", telemetry_is_fixed_point},
  {"knots_pack_with_and_without_gains", knots_pack_with_and_without_gains},
  {"knot_ring_takes_whole_messages_in_order_within_its_slots",
   knot_ring_takes_whole_messages_in_order_within_its_slots},
  {"knot_ring_streams_a_motion_longer_than_itself", knot_ring_streams_a_motion_longer_than_itself},
  {"server_executes_once_repeats_and_refuses", server_executes_once_repeats_and_refuses},
  {"a_robot_is_checked_by_the_cores_checks", a_robot_is_checked_by_the_cores_checks},
  {0, 0},
};
