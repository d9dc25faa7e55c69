// test_dxl.c: the Dynamixel Protocol 2.0 codec (hal/dynamixel/c/dxl.h) against the e-manual's
// example packets byte for byte, the stuffing rule at every boundary, and the reader on garbage,
// corruption, truncation, impossible headers, oversized frames and long random streams.
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include "dxl.h"
#include "harness.h"

enum { BUF = 1024 };

//---------------------------------- helpers ------------------------------------------------------

// "FF FF FD 00 ..." -> bytes; returns the count
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

// got[0..n) equals the hex text: same length, and the first difference is past the end
static void expect_bytes(const uint8_t* got, size_t n, const char* text, const char* reason) {
  uint8_t want[BUF];
  size_t m = hex(text, want), i = 0;
  EXPECT_INT(n, m, reason);
  while (i < n && i < m && got[i] == want[i]) i++;
  EXPECT_INT(i, m, reason);   // measured = index of the first differing byte
}

static int same_bytes(const uint8_t* a, const uint8_t* b, size_t n) {
  return n == 0 || memcmp(a, b, n) == 0;
}

// deterministic pseudo-random bytes (xorshift32)
static uint32_t next_random(uint32_t* s) {
  *s ^= *s << 13;
  *s ^= *s >> 17;
  *s ^= *s << 5;
  return *s;
}

// a byte that often forms FF FF FD, the pattern stuffing is about
static uint8_t stuffable_byte(uint32_t* s) {
  static const uint8_t pick[6] = {0xFF, 0xFF, 0xFD, 0x00, 0x55, 0x01};
  uint32_t x = next_random(s);
  return x % 4 ? pick[(x >> 8) % 6] : (uint8_t)(x >> 16);
}

//---------------------------------- the reader's events ------------------------------------------

// What the reader reported, in order: every result but DXL_MORE, with the index of the byte
// that caused it and, for a packet, a copy of its fields (they last only until the next byte).
typedef struct event_ {
  int code;
  size_t at;
  uint8_t id, instruction, error;
  uint16_t nparam;
  uint8_t param[DXL_MAX_PARAM];
} event;

enum { MAX_EVENTS = 8 };
static dxl_reader g_reader;
static event g_events[MAX_EVENTS];
static int g_nevents;
static size_t g_fed;

static void start_reading(void) {
  dxl_reader_reset(&g_reader);
  g_nevents = 0;
  g_fed = 0;
}

static void feed(const uint8_t* p, size_t n) {
  for (size_t i = 0; i < n; i++, g_fed++) {
    int code = dxl_reader_feed(&g_reader, p[i]);
    if (code == DXL_MORE || g_nevents == MAX_EVENTS) continue;
    event* e = &g_events[g_nevents++];
    e->code = code;
    e->at = g_fed;
    e->id = g_reader.id;
    e->instruction = g_reader.instruction;
    e->error = g_reader.error;
    e->nparam = g_reader.nparam;
    memcpy(e->param, g_reader.param, g_reader.nparam);
  }
}

static void feed_hex(const char* text) {
  uint8_t bytes[BUF];
  feed(bytes, hex(text, bytes));
}

// event k is a packet with these fields; params as hex
static void expect_packet(int k, uint8_t id, uint8_t instruction, uint8_t error,
                          const char* params, const char* reason) {
  EXPECT_INT(g_nevents > k, 1, reason);
  if (g_nevents <= k) return;
  const event* e = &g_events[k];
  EXPECT_INT(e->code, DXL_PACKET, reason);
  EXPECT_INT(e->id, id, reason);
  EXPECT_INT(e->instruction, instruction, reason);
  EXPECT_INT(e->error, error, reason);
  expect_bytes(e->param, e->nparam, params, reason);
}

static void expect_codes(const int* codes, int n, const char* reason) {
  EXPECT_INT(g_nevents, n, reason);
  for (int k = 0; k < n && k < g_nevents; k++) EXPECT_INT(g_events[k].code, codes[k], reason);
}

// a status packet: ERR then params after INST 0x55
static size_t status_packet(uint8_t* out, uint8_t id, uint8_t error, const char* params) {
  uint8_t p[BUF];
  p[0] = error;
  size_t n = hex(params, p + 1);
  return dxl_packet(out, BUF, id, DXL_STATUS, p, n + 1);
}

// A fast read reply built the independent way: the frame so far is in out, so each block's CRC
// is simply the CRC of out[0..n). blocks: per servo ERR ID DATA, data of size[k] bytes.
static size_t fast_reply(uint8_t* out, const uint8_t* blocks, const uint16_t* size, size_t count) {
  size_t n = 8, length = 1;
  for (size_t k = 0; k < count; k++) length += size[k] + 4u;
  static const uint8_t head[8] = {0xFF, 0xFF, 0xFD, 0x00, 0xFE, 0, 0, 0x55};
  memcpy(out, head, 8);
  dxl_put_u16(out + 5, (uint16_t)length);
  for (size_t k = 0; k < count; k++) {
    memcpy(out + n, blocks, size[k] + 2u);
    blocks += size[k] + 2u;
    n += size[k] + 2u;
    dxl_put_u16(out + n, dxl_crc(0, out, n));
    n += 2;
  }
  return n;
}

//---------------------------------- CRC ----------------------------------------------------------

static void crc_is_the_emanual_crc16(void) {
  EXPECT_INT(dxl_crc(0, (const uint8_t*)"123456789", 9), 0xFEE8,
             "CRC-16/UMTS (poly 0x8005, init 0, no reflection): the catalogue check value");
  uint8_t p[BUF];
  size_t n = hex("FF FF FD 00 01 03 00 01", p);
  EXPECT_INT(dxl_crc(0, p, n), 0x4E19, "e-manual: ping ID 1 has CRC 0x4E19");
  n = hex("FF FF FD 00 FE 03 00 01", p);
  EXPECT_INT(dxl_crc(0, p, n), 0x4231, "e-manual: broadcast ping has CRC 0x4231");
  n = hex("FF FF FD 00 01 07 00 55 00 06 04 26", p);
  EXPECT_INT(dxl_crc(0, p, n), 0x5D65, "e-manual: ping status of ID 1 has CRC 0x5D65");
  for (size_t k = 0; k <= n; k++) {
    EXPECT_INT(dxl_crc(dxl_crc(0, p, k), p + k, n - k), 0x5D65, "the CRC continues across calls");
  }
  EXPECT_INT(dxl_crc(0x1234, p, 0), 0x1234, "no bytes leave the CRC as it was");
}

//---------------------------------- e-manual packets ---------------------------------------------

static void emanual_instruction_packets(void) {
  uint8_t out[BUF], p[BUF];
  size_t n;
  sdt_context("ping ID 1");
  expect_bytes(out, dxl_ping(out, BUF, 1), "FF FF FD 00 01 03 00 01 19 4E", "e-manual ping");
  sdt_context("broadcast ping");
  expect_bytes(out, dxl_ping(out, BUF, DXL_BROADCAST), "FF FF FD 00 FE 03 00 01 31 42",
               "e-manual broadcast ping");
  sdt_context("read Present Position(132), 4 bytes");
  expect_bytes(out, dxl_read(out, BUF, 1, 132, 4), "FF FF FD 00 01 07 00 02 84 00 04 00 1D 15",
               "e-manual read");
  sdt_context("write Goal Position(116) = 512");
  dxl_put_u32(p, 512);
  expect_bytes(out, dxl_write(out, BUF, 1, 116, p, 4),
               "FF FF FD 00 01 09 00 03 74 00 00 02 00 00 CA 89", "e-manual write");
  sdt_context("reg write Goal Velocity(104) = 200");
  n = hex("68 00 C8 00 00 00", p);
  expect_bytes(out, dxl_packet(out, BUF, 1, DXL_REG_WRITE, p, n),
               "FF FF FD 00 01 09 00 04 68 00 C8 00 00 00 AE 8E", "e-manual reg write");
  sdt_context("action");
  expect_bytes(out, dxl_packet(out, BUF, 1, DXL_ACTION, NULL, 0), "FF FF FD 00 01 03 00 05 02 CE",
               "e-manual action");
  sdt_context("factory reset, all but the ID");
  p[0] = 0x01;
  expect_bytes(out, dxl_packet(out, BUF, 1, DXL_FACTORY_RESET, p, 1),
               "FF FF FD 00 01 04 00 06 01 A1 E6", "e-manual factory reset");
  sdt_context("reboot");
  expect_bytes(out, dxl_reboot(out, BUF, 1), "FF FF FD 00 01 03 00 08 2F 4E", "e-manual reboot");
  sdt_context("clear multi-turn");
  n = hex("01 44 58 4C 22", p);
  expect_bytes(out, dxl_packet(out, BUF, 1, DXL_CLEAR, p, n),
               "FF FF FD 00 01 08 00 10 01 44 58 4C 22 B1 DC", "e-manual clear");
}

static void emanual_group_packets(void) {
  uint8_t out[BUF], p[BUF];
  sdt_context("sync read Present Position of ID 1, 2");
  const uint8_t ids12[2] = {1, 2};
  expect_bytes(out, dxl_sync_read(out, BUF, 132, 4, ids12, 2),
               "FF FF FD 00 FE 09 00 82 84 00 04 00 01 02 CE FA", "e-manual sync read");
  sdt_context("sync write Goal Position 150 to ID 1, 170 to ID 2");
  dxl_put_u32(p, 150);
  dxl_put_u32(p + 4, 170);
  expect_bytes(out, dxl_sync_write(out, BUF, 116, 4, ids12, 2, p),
               "FF FF FD 00 FE 11 00 83 74 00 04 00 01 96 00 00 00 02 AA 00 00 00 82 87",
               "e-manual sync write");
  sdt_context("fast sync read Present Position of ID 3, 7, 4");
  const uint8_t ids374[3] = {3, 7, 4};
  expect_bytes(out, dxl_fast_sync_read(out, BUF, 132, 4, ids374, 3),
               "FF FF FD 00 FE 0A 00 8A 84 00 04 00 03 07 04 20 F2", "e-manual fast sync read");
  sdt_context("bulk read: 2 bytes at 144 of ID 1, 1 byte at 146 of ID 2");
  const uint16_t addr_b[2] = {144, 146}, size_b[2] = {2, 1};
  expect_bytes(out, dxl_bulk_read(out, BUF, ids12, addr_b, size_b, 2),
               "FF FF FD 00 FE 0D 00 92 01 90 00 02 00 02 92 00 01 00 1A 05", "e-manual bulk read");
  sdt_context("bulk write: A0 00 at 32 of ID 1, 50 at 31 of ID 2");
  size_t n = hex("01 20 00 02 00 A0 00 02 1F 00 01 00 50", p);
  expect_bytes(out, dxl_packet(out, BUF, DXL_BROADCAST, DXL_BULK_WRITE, p, n),
               "FF FF FD 00 FE 10 00 93 01 20 00 02 00 A0 00 02 1F 00 01 00 50 B7 68",
               "e-manual bulk write");
  // The e-manual prints CRC 20 F2 here, the fast sync read example's CRC copied; every other
  // byte matches, and the CRC-16 of them is 0x2DDA (as on the Python side).
  sdt_context("fast bulk read: 4 at 132 of ID 3, 2 at 124 of ID 7, 1 at 146 of ID 4");
  const uint16_t addr_f[3] = {132, 124, 146}, size_f[3] = {4, 2, 1};
  expect_bytes(out, dxl_fast_bulk_read(out, BUF, ids374, addr_f, size_f, 3),
               "FF FF FD 00 FE 12 00 9A 03 84 00 04 00 07 7C 00 02 00 04 92 00 01 00 DA 2D",
               "e-manual fast bulk read, with the CRC of its bytes");
}

static const struct {
  uint8_t id;
  const char* params;
  const char* frame;
} k_status[] = {
  {1, "06 04 26", "FF FF FD 00 01 07 00 55 00 06 04 26 65 5D"},
  {2, "06 04 26", "FF FF FD 00 02 07 00 55 00 06 04 26 6F 6D"},
  {1, "A6 00 00 00", "FF FF FD 00 01 08 00 55 00 A6 00 00 00 8C C0"},
  {2, "1F 08 00 00", "FF FF FD 00 02 08 00 55 00 1F 08 00 00 BA BE"},
  {1, "", "FF FF FD 00 01 04 00 55 00 A1 0C"},
  {1, "77 00", "FF FF FD 00 01 06 00 55 00 77 00 C3 69"},
  {2, "24", "FF FF FD 00 02 05 00 55 00 24 8B A9"},
};

static void emanual_status_packets(void) {
  uint8_t out[BUF], frame[BUF];
  for (size_t k = 0; k < sizeof k_status / sizeof k_status[0]; k++) {
    sdt_context("e-manual status %s", k_status[k].frame);
    expect_bytes(out, status_packet(out, k_status[k].id, 0, k_status[k].params), k_status[k].frame,
                 "a status packet built with dxl_packet is the e-manual's");
    size_t n = hex(k_status[k].frame, frame);
    start_reading();
    feed(frame, n);
    EXPECT_INT(g_nevents, 1, "one event: the packet");
    EXPECT_INT(g_events[0].at, n - 1, "it completes on the last CRC byte, not before");
    expect_packet(0, k_status[k].id, DXL_STATUS, 0, k_status[k].params, "ID, ERR and params back");
  }
}

//---------------------------------- fast read replies --------------------------------------------

static const char k_fast_sync_reply[] =
    "FF FF FD 00 FE 19 00 55 00 03 A6 00 00 00 84 08 00 07 1F 08 00 00 16 CA "
    "00 04 FF 03 00 00 D1 9E";
static const char k_fast_bulk_reply[] =
    "FF FF FD 00 FE 14 00 55 00 03 A6 00 00 00 67 A4 00 07 A5 01 24 74 00 04 1F D9 C1";

// read a reply and split it; returns what the split returned
static int read_and_split(const uint8_t* frame, size_t n, const uint16_t* sizes, uint16_t size,
                          const uint8_t* ids, size_t count, dxl_block* blocks) {
  start_reading();
  feed(frame, n);
  EXPECT_INT(g_nevents == 1 && g_events[0].code == DXL_PACKET, 1, "the reply is one good packet");
  return sizes ? dxl_fast_bulk_reply_split(&g_reader, sizes, ids, count, blocks)
               : dxl_fast_reply_split(&g_reader, size, ids, count, blocks);
}

static void fast_sync_reply_of_the_emanual(void) {
  uint8_t frame[BUF];
  size_t n = hex(k_fast_sync_reply, frame);
  // the e-manual's bytes settle what a block's CRC covers: the whole frame up to it
  EXPECT_INT(dxl_get_u16(frame + 14), dxl_crc(0, frame, 14), "block 1 CRC = CRC of frame[0..14)");
  EXPECT_INT(dxl_get_u16(frame + 22), dxl_crc(0, frame, 22), "block 2 CRC covers block 1's CRC");
  const uint8_t ids[3] = {3, 7, 4};
  const uint16_t sizes[3] = {4, 4, 4};
  uint8_t built[BUF];
  expect_bytes(built, fast_reply(built, (const uint8_t*)"\x00\x03\xA6\x00\x00\x00"
                                                         "\x00\x07\x1F\x08\x00\x00"
                                                         "\x00\x04\xFF\x03\x00\x00", sizes, 3),
               k_fast_sync_reply, "the test's own reply builder agrees with the e-manual");
  dxl_block b[3];
  int got = read_and_split(frame, n, NULL, 4, ids, 3, b);
  EXPECT_INT(got, 3, "three good blocks");
  EXPECT_INT(g_reader.nparam, 3 * 8 - 3, "params: 3 blocks of ERR ID DATA(4) CRC(2), less the "
                                         "first ERR (the packet's) and the last CRC (the packet's)");
  static const uint32_t position[3] = {166, 2079, 1023};
  for (int k = 0; k < got; k++) {
    EXPECT_INT(b[k].id, ids[k], "blocks in request order");
    EXPECT_INT(b[k].error, 0, "no error");
    EXPECT_INT(dxl_get_u32(b[k].data), position[k], "e-manual Present Position values");
  }
}

static void fast_bulk_reply_of_the_emanual(void) {
  uint8_t frame[BUF];
  size_t n = hex(k_fast_bulk_reply, frame);
  const uint8_t ids[3] = {3, 7, 4};
  const uint16_t sizes[3] = {4, 2, 1};
  dxl_block b[3];
  int got = read_and_split(frame, n, sizes, 0, ids, 3, b);
  EXPECT_INT(got, 3, "blocks of 4, 2 and 1 bytes");
  if (got != 3) return;
  EXPECT_INT(dxl_get_u32(b[0].data), 166, "Present Position of ID 3");
  EXPECT_INT(dxl_get_u16(b[1].data), 421, "2 bytes at 124 of ID 7");
  EXPECT_INT(b[2].data[0], 0x1F, "Present Temperature of ID 4");
}

// the e-manual reply with one byte changed and the packet CRC made good again
static size_t damaged_reply(uint8_t* frame, size_t at, uint8_t value) {
  size_t n = hex(k_fast_sync_reply, frame);
  frame[at] = value;
  dxl_put_u16(frame + n - 2, dxl_crc(0, frame, n - 2));
  return n;
}

static void fast_reply_faults_name_the_first_bad_block(void) {
  uint8_t frame[BUF];
  const uint8_t ids[4] = {3, 7, 4, 9};
  dxl_block b[4];
  size_t n = damaged_reply(frame, 14, 0x85);
  EXPECT_INT(read_and_split(frame, n, NULL, 4, ids, 3, b), 0, "block 0's CRC is wrong");
  n = damaged_reply(frame, 22, 0x00);
  b[0].id = 0;
  EXPECT_INT(read_and_split(frame, n, NULL, 4, ids, 3, b), 1, "block 1's CRC is wrong");
  EXPECT_INT(b[0].id, 3, "block 0 before it is filled");
  n = damaged_reply(frame, 17, 0x08);
  EXPECT_INT(read_and_split(frame, n, NULL, 4, ids, 3, b), 1, "block 1 answers for ID 8, not 7");
  n = damaged_reply(frame, 18, 0x20);
  EXPECT_INT(read_and_split(frame, n, NULL, 4, ids, 3, b), 1, "a data byte of block 1 changed");
  n = damaged_reply(frame, 27, 0x04);
  EXPECT_INT(read_and_split(frame, n, NULL, 4, ids, 3, b), 3,
             "the last block is checked by the packet CRC alone, made good here");
  n = hex(k_fast_sync_reply, frame);
  EXPECT_INT(read_and_split(frame, n, NULL, 4, ids, 4, b), 3, "asked for 4: the fourth is missing");
  EXPECT_INT(read_and_split(frame, n, NULL, 4, ids, 2, b), 1,
             "asked for 2: bytes follow the last block, so it is not the reply asked for");
  EXPECT_INT(read_and_split(frame, n, NULL, 2, ids, 3, b), 0, "asked for 2-byte data: garbled");
  EXPECT_INT(read_and_split(frame, n, NULL, 5, ids, 3, b), 0, "asked for 5-byte data: garbled");
  EXPECT_INT(read_and_split(frame, n, NULL, 4, ids, 0, b), 0, "asked for none");
  n = hex(k_status[2].frame, frame);
  EXPECT_INT(read_and_split(frame, n, NULL, 4, ids, 1, b), 0, "a status packet from ID 1 is no reply");
}

static void fast_reply_carries_each_servos_error(void) {
  uint8_t frame[BUF];
  const uint8_t blocks[] = {0x80, 5, 0xFF, 0xFF, 0x07, 1, 0xFD, 0x00, 2, 0xFF, 0xFF, 0xFD, 0x00};
  const uint16_t sizes[3] = {2, 1, 4};
  const uint8_t ids[3] = {5, 1, 2};
  size_t n = fast_reply(frame, blocks, sizes, 3);
  dxl_block b[3];
  int got = read_and_split(frame, n, sizes, 0, ids, 3, b);
  EXPECT_INT(got, 3, "three blocks of 2, 1 and 4 bytes");
  if (got != 3) return;
  EXPECT_INT(b[0].error, 0x80, "the first servo's ERR is the packet's: alert");
  EXPECT_INT(b[1].error, 0x07, "the second servo's own ERR: access error");
  EXPECT_INT(b[2].error, 0x00, "the third's");
  EXPECT_INT(dxl_get_i16(b[0].data), -1, "FF FF comes through unstuffed");
  EXPECT_INT(b[1].data[0], 0xFD, "and the FD after it");
  EXPECT_INT(dxl_get_u32(b[2].data), 0x00FDFFFFu, "FF FF FD 00 inside a reply is data, not a header");
}

static void fast_reply_is_never_stuffed(void) {
  uint8_t out[BUF];
  const uint8_t p[6] = {0x00, 0x01, 0xFF, 0xFF, 0xFD, 0xFD};
  size_t n = dxl_packet(out, BUF, DXL_BROADCAST, DXL_STATUS, p, 6);
  EXPECT_INT(n, 16, "LEN 9: INST, ERR, ID, 4 data, CRC; nothing added");
  expect_bytes(out + 5, 2, "09 00", "LEN 9");
  expect_bytes(out + 9, 5, "01 FF FF FD FD", "ID and data go out as they are");
  start_reading();
  feed(out, n);
  expect_packet(0, DXL_BROADCAST, DXL_STATUS, 0, "01 FF FF FD FD",
                "the reader does not unstuff a status packet from 0xFE");
  n = dxl_packet(out, BUF, 1, DXL_STATUS, p, 6);
  EXPECT_INT(n, 17, "from ID 1 the same bytes are stuffed");
}

//---------------------------------- stuffing -----------------------------------------------------

// instruction and params -> the stuffed body on the wire; then the reader gives them back
static void expect_stuffed(uint8_t instruction, const char* params, const char* wire) {
  uint8_t p[BUF], out[BUF];
  size_t np = hex(params, p);
  size_t n = dxl_packet(out, BUF, 1, instruction, p, np);
  expect_bytes(out + 7, n - 9, wire, "stuffed body (INST and params)");
  EXPECT_INT(dxl_get_u16(out + 5), n - 7, "LEN counts the stuffed bytes, INST and CRC");
  EXPECT_INT(dxl_get_u16(out + n - 2), dxl_crc(0, out, n - 2), "CRC over the stuffed bytes");
  start_reading();
  feed(out, n);
  size_t skip = instruction == DXL_STATUS;   // the ERR byte
  const event* e = &g_events[0];
  EXPECT_INT(g_nevents == 1 && e->code == DXL_PACKET && e->instruction == instruction, 1,
             "the stuffed packet is read");
  EXPECT_INT(e->error, skip ? p[0] : 0, "ERR of a status packet, else 0");
  EXPECT_INT(e->nparam == np - skip && same_bytes(e->param, p + skip, np - skip), 1,
             "the reader removes exactly the stuffing");
}

static void stuffing_at_every_boundary(void) {
  static const struct {
    uint8_t inst;
    const char *params, *wire, *why;
  } k[] = {
    {0x03, "FF FF FD", "03 FF FF FD FD", "the whole params are the pattern (ends before the CRC)"},
    {0x03, "FF FF FD 00", "03 FF FF FD FD 00", "a whole header in the params"},
    {0x03, "FF FF FD FF FF FD 00", "03 FF FF FD FD FF FF FD FD 00", "every occurrence"},
    {0x03, "FF FF FD FD", "03 FF FF FD FD FD", "an FD after the pattern is data, stuffed anyway"},
    {0x03, "FF FF FF FD", "03 FF FF FF FD FD", "a third FF: the pattern starts one later"},
    {0x03, "FF FD FF FF", "03 FF FD FF FF", "no full pattern, nothing added"},
    {0x03, "00 FF FF", "03 00 FF FF", "FF FF at the end, then the CRC: nothing added"},
    {0x03, "FF FF FD FD FD", "03 FF FF FD FD FD FD", "FD FD after the pattern"},
    {0xFF, "FF FD", "FF FF FD FD", "the pattern starts at INST: stuffing covers it too"},
    {0x55, "FF FF FD 01", "55 FF FF FD FD 01", "ERR FF of a status packet starts it"},
  };
  for (size_t i = 0; i < sizeof k / sizeof k[0]; i++) {
    sdt_context("INST %02X params %s: %s", k[i].inst, k[i].params, k[i].why);
    expect_stuffed(k[i].inst, k[i].params, k[i].wire);
  }
  uint8_t out[BUF];
  const uint8_t fd = 0xFD;
  sdt_context("write of FD at address 0xFFFF");
  size_t n = dxl_write(out, BUF, 1, 0xFFFF, &fd, 1);
  expect_bytes(out + 5, n - 7, "07 00 03 FF FF FD FD", "address FF FF and data FD form the pattern");
  sdt_context("read of 253 bytes at address 0xFFFF");
  n = dxl_read(out, BUF, 1, 0xFFFF, 0xFD);
  expect_bytes(out + 7, n - 9, "02 FF FF FD FD 00", "address and size form the pattern");
  sdt_context("write of FF FF FD FD at 100 (Goal PWM -1, Goal Current -515)");
  const uint8_t data[4] = {0xFF, 0xFF, 0xFD, 0xFD};
  n = dxl_write(out, BUF, 1, 100, data, 4);
  expect_bytes(out + 5, 10, "0A 00 03 64 00 FF FF FD FD FD", "as the Python codec: LEN 10");
}

static void status_with_present_current_minus_one(void) {
  // a read of 126..131: Present Current -1 (FF FF) then Present Velocity -3 (FD FF FF FF)
  uint8_t out[BUF];
  size_t n = status_packet(out, 1, 0, "FF FF FD FF FF FF");
  expect_bytes(out, 7, "FF FF FD 00 01 0B 00", "LEN 11: INST, ERR, 6 data + 1 stuffed byte, CRC");
  expect_bytes(out + 7, 9, "55 00 FF FF FD FD FF FF FF", "an FD inserted after FF FF FD");
  start_reading();
  feed(out, n);
  expect_packet(0, 1, DXL_STATUS, 0, "FF FF FD FF FF FF", "unstuffed");
  EXPECT_INT(dxl_get_i16(g_events[0].param), -1, "Present Current -1");
  EXPECT_INT(dxl_get_i32(g_events[0].param + 2), -3, "Present Velocity -3");
}

//---------------------------------- the reader ---------------------------------------------------

static void reader_skips_garbage_before_a_packet(void) {
  static const char* garbage[] = {
    "", "00", "FF", "FF FF", "FF FF FD", "FF FF FF FD", "FF FF FD FF FF", "FD 00 FE 55 FF FD 00 FF",
    "FF FF FD FD 00", "55 00 06 04 26 65 5D",
  };
  uint8_t frame[BUF];
  size_t n = hex(k_status[0].frame, frame);
  for (size_t k = 0; k < sizeof garbage / sizeof garbage[0]; k++) {
    sdt_context("garbage \"%s\" before a ping status", garbage[k]);
    start_reading();
    feed_hex(garbage[k]);
    size_t before = g_fed;
    feed(frame, n);
    EXPECT_INT(g_nevents, 1, "garbage makes no event; the packet one");
    EXPECT_INT(g_events[0].at, before + n - 1, "on its last byte");
    expect_packet(0, 1, DXL_STATUS, 0, "06 04 26", "the packet after the garbage");
  }
}

static void reader_reports_a_bad_crc_and_goes_on(void) {
  uint8_t bad[BUF], ping[32];
  uint8_t pos[4];
  dxl_put_u32(pos, 512);
  size_t n = dxl_write(bad, BUF, 1, 116, pos, 4);
  for (size_t at = 0; at < n; at++) {
    for (int bit = 0; bit < 8; bit++) {
      sdt_context("write Goal Position with bit %d of byte %zu flipped, then a ping", bit, at);
      bad[at] ^= (uint8_t)(1u << bit);
      start_reading();
      feed(bad, n);
      size_t np = dxl_ping(ping, sizeof ping, 2);
      feed(ping, np);
      bad[at] ^= (uint8_t)(1u << bit);
      int found = 0;
      for (int k = 0; k < g_nevents; k++) found += g_events[k].code == DXL_PACKET;
      EXPECT_INT(found, 1, "only the ping comes out: the damaged write never does");
      const event* last = &g_events[g_nevents ? g_nevents - 1 : 0];
      EXPECT_INT(g_nevents && last->code == DXL_PACKET && last->id == 2, 1, "the ping arrives, last");
    }
  }
  sdt_context("a data bit flipped");
  bad[10] ^= 0x40;
  start_reading();
  feed(bad, n);
  feed(ping, dxl_ping(ping, sizeof ping, 2));
  static const int codes[2] = {DXL_BAD_CRC, DXL_PACKET};
  expect_codes(codes, 2, "the CRC error on the write's last byte, then the ping");
  EXPECT_INT(g_events[0].at, n - 1, "reported when the frame is complete");
}

static void reader_recovers_a_packet_sent_inside_a_truncated_one(void) {
  uint8_t out[BUF];
  start_reading();
  feed(out, dxl_read(out, BUF, 1, 132, 4) - 6);   // LEN promises 6 more bytes than come
  size_t n = dxl_ping(out, BUF, 3);
  feed(out, n);
  feed_hex("00 00 00 00");
  static const int codes[2] = {DXL_BAD_FRAME, DXL_PACKET};
  expect_codes(codes, 2, "the cut frame is dropped at the next header, the ping comes whole");
  EXPECT_INT(g_events[0].at, 8 + 3, "dropped on the 00 that completes the ping's header");
  expect_packet(1, 3, DXL_PING, 0, "", "the ping inside");
  // a status packet cut short by another
  start_reading();
  feed(out, status_packet(out, 4, 0, "01 02 03 04 05 06") - 5);
  feed(out, status_packet(out, 5, 0x80, "FF FF FD 00"));
  expect_codes(codes, 2, "a cut status packet, then a whole one");
  expect_packet(1, 5, DXL_STATUS, 0x80, "FF FF FD 00", "the second packet, unstuffed");
}

static void reader_rejects_impossible_headers_at_once(void) {
  static const struct {
    const char* head;
    int code;
    const char* why;
  } k[] = {
    {"FF FF FD 00 01 02 00", DXL_BAD_FRAME, "LEN 2 < 3"},
    {"FF FF FD 00 FF 03 00", DXL_BAD_FRAME, "ID 0xFF does not exist"},
    {"FF FF FD 00 FD 03 00", DXL_BAD_FRAME, "ID 0xFD does not exist"},
    {"FF FF FD 00 01 FF FF", DXL_TOO_LONG, "LEN 65535 cannot fit"},
    {"FF FF FD 00", DXL_BAD_FRAME, "a header then the ping's: its first FF is a bad ID, and a start"},
  };
  uint8_t ping[32];
  size_t n = dxl_ping(ping, sizeof ping, 5);
  for (size_t i = 0; i < sizeof k / sizeof k[0]; i++) {
    sdt_context("%s then a ping: %s", k[i].head, k[i].why);
    start_reading();
    feed_hex(k[i].head);
    feed(ping, n);
    const int codes[2] = {k[i].code, DXL_PACKET};
    expect_codes(codes, 2, "the bad header at once, then the ping");
    expect_packet(1, 5, DXL_PING, 0, "", "the ping is not lost");
  }
  sdt_context("a status packet without ERR");
  uint8_t out[32];
  start_reading();
  feed(out, dxl_packet(out, sizeof out, 1, DXL_STATUS, NULL, 0));
  feed(ping, n);
  static const int codes[2] = {DXL_BAD_FRAME, DXL_PACKET};
  expect_codes(codes, 2, "LEN 3 with INST 0x55: no ERR byte, a bad frame; then the ping");
}

static void reader_refuses_packets_too_long(void) {
  static uint8_t p[2 * DXL_MAX_PARAM], out[4 * DXL_MAX_PARAM];
  for (int i = 0; i < 2 * DXL_MAX_PARAM; i++) p[i] = (uint8_t)"\xFF\xFF\xFD"[i % 3];
  sdt_context("a status packet of DXL_MAX_PARAM params, a third of them stuffed");
  size_t n = dxl_packet(out, sizeof out, 1, DXL_STATUS, p, DXL_MAX_PARAM + 1);
  start_reading();
  feed(out, n);
  EXPECT_INT(g_nevents == 1 && g_events[0].code == DXL_PACKET, 1, "the largest packet is read");
  EXPECT_INT(g_events[0].nparam, DXL_MAX_PARAM, "all its params");
  EXPECT_INT(same_bytes(g_events[0].param, p + 1, DXL_MAX_PARAM), 1, "unstuffed");

  sdt_context("one param more");
  n = dxl_packet(out, sizeof out, 1, DXL_STATUS, p, DXL_MAX_PARAM + 2);
  start_reading();
  feed(out, n);
  EXPECT_INT(g_nevents, 1, "one event");
  EXPECT_INT(g_events[0].code, DXL_TOO_LONG, "refused");
  EXPECT_INT(g_events[0].at, 6, "at once, on LEN: it cannot fit however it is stuffed");

  sdt_context("LEN that could fit stuffed params, and unstuffed ones that do not");
  memset(p, 0x11, sizeof p);
  n = dxl_packet(out, sizeof out, 1, DXL_STATUS, p, DXL_MAX_PARAM + 40);
  start_reading();
  feed(out, n);
  uint8_t ping[32];
  feed(ping, dxl_ping(ping, sizeof ping, 7));
  static const int codes[2] = {DXL_TOO_LONG, DXL_PACKET};
  expect_codes(codes, 2, "refused when the buffer is full, then the next packet");
  EXPECT_INT(g_events[0].at, 7 + 2 + DXL_MAX_PARAM, "on the first param that does not fit");
  expect_packet(1, 7, DXL_PING, 0, "", "the ping after it");
}

// the status packet from ID 1 whose params end in FF FF and whose CRC is FD 00: its last four
// bytes are a header. 16 free bits before them reach every CRC, so the search finds one.
static size_t packet_ending_in_a_header(uint8_t* out) {
  uint8_t p[5] = {0, 0, 0, 0xFF, 0xFF};
  for (uint32_t x = 0; x < 0x10000; x++) {
    p[1] = (uint8_t)x;
    p[2] = (uint8_t)(x >> 8);
    size_t n = dxl_packet(out, BUF, 1, DXL_STATUS, p, 5);
    if (out[n - 2] == 0xFD && out[n - 1] == 0x00) return n;
  }
  return 0;
}

static void reader_takes_a_header_in_the_crc_as_the_crc(void) {
  uint8_t out[BUF];
  size_t n = packet_ending_in_a_header(out);
  EXPECT_INT(n, 15, "such a packet exists");
  start_reading();
  feed(out, n);
  uint8_t ping[32];
  feed(ping, dxl_ping(ping, sizeof ping, 9));
  static const int codes[2] = {DXL_PACKET, DXL_PACKET};
  expect_codes(codes, 2, "the packet ending in FF FF FD 00 is good, and so is the next");
  // with its CRC damaged the tail is a header again, and a frame begins there
  out[n - 5] ^= 0x01;
  start_reading();
  feed(out, n);
  feed_hex("09 03 00 01");   // the rest of a ping to ID 9 after FF FF FD 00
  feed(ping + 8, 2);
  static const int bad[2] = {DXL_BAD_CRC, DXL_PACKET};
  expect_codes(bad, 2, "a bad CRC; then its last four bytes begin the next frame");
  expect_packet(1, 9, DXL_PING, 0, "", "the ping that shares them");
}

static void reader_reset_forgets_a_partial_packet(void) {
  uint8_t out[BUF];
  size_t n = status_packet(out, 1, 0, "01 02 03");
  start_reading();
  feed(out, n - 3);
  dxl_reader_reset(&g_reader);
  feed(out + n - 3, 3);
  feed(out, n);
  EXPECT_INT(g_nevents, 1, "the head before the reset is forgotten, its tail is garbage");
  expect_packet(0, 1, DXL_STATUS, 0, "01 02 03", "the whole packet after it");
}

static void reader_reads_long_random_streams(void) {
  uint32_t seed = 12345;
  uint8_t p[64], out[BUF];
  static const uint8_t garbage[5] = {0x00, 0x01, 0xFD, 0x55, 0x80};   // no FF: no fake header
  int good = 0, stuffed = 0;
  start_reading();
  for (int trial = 0; trial < 3000; trial++) {
    uint8_t id = (uint8_t)(next_random(&seed) % 254);
    if (id == 0xFD) id = DXL_BROADCAST;
    uint8_t inst = trial % 3 ? DXL_STATUS : stuffable_byte(&seed);
    size_t np = next_random(&seed) % 41 + (inst == DXL_STATUS);
    for (size_t i = 0; i < np; i++) p[i] = stuffable_byte(&seed);
    size_t n = dxl_packet(out, BUF, id, inst, p, np);
    stuffed += n != np + 10;
    for (uint32_t g = next_random(&seed) % 6; g > 0; g--) {
      uint8_t byte = garbage[next_random(&seed) % 5];
      feed(&byte, 1);
    }
    g_nevents = 0;
    feed(out, n);
    sdt_context("trial %d: ID %u, INST %02X, %zu params", trial, id, inst, np);
    int ok = g_nevents == 1 && g_events[0].code == DXL_PACKET && g_events[0].id == id &&
             g_events[0].instruction == inst;
    size_t skip = inst == DXL_STATUS;   // ERR
    ok = ok && g_events[0].error == (skip ? p[0] : 0) && g_events[0].nparam == np - skip &&
         same_bytes(g_events[0].param, p + skip, np - skip);
    good += ok;
    if (!ok) EXPECT_INT(ok, 1, "the packet comes back whole");
  }
  sdt_context("3000 packets");
  EXPECT_INT(good, 3000, "every packet read back with its fields");
  EXPECT_GE(stuffed, 300, "and many of them needed stuffing");
}

//---------------------------------- many bytes a call --------------------------------------------
// dxl_reader_feed_bytes must be dxl_reader_feed over the same bytes: g_reader takes them one at a
// time (feed, the events above), g_bulk the same bytes in chunks through dxl_reader_feed_bytes.

static dxl_reader g_bulk;
static int g_bulk_codes[5];     // the results seen, DXL_BAD_FRAME..DXL_PACKET at [code + 3]
static int g_bulk_fast;         // whole 7 x 10 fast replies read
static int g_bulk_fast_header;  // of them, with FF FF FD 00 in their data

// two fresh readers: reset leaves the fields of the last frame, which are compared below
static void start_both(void) {
  memset(&g_reader, 0, sizeof g_reader);
  memset(&g_bulk, 0, sizeof g_bulk);
  start_reading();
  dxl_reader_reset(&g_bulk);
}

// The whole state but tail, which only a stuffed frame reads: in a fast reply raw_run leaves it
// 0 while the byte path keeps shifting bytes in, and the next frame clears it.
static int same_reader(const dxl_reader* a, const dxl_reader* b) {
  return a->state == b->state && a->window == b->window && a->crc == b->crc &&
         a->remain == b->remain && a->nbody == b->nbody && a->raw == b->raw &&
         a->crc_low == b->crc_low && (a->raw || a->tail == b->tail) && a->id == b->id &&
         a->instruction == b->instruction && a->error == b->error && a->nparam == b->nparam &&
         same_bytes(a->param, b->param, a->nparam);
}

static int has_header(const uint8_t* p, size_t n) {
  for (size_t i = 0; i + 4 <= n; i++) {
    if (p[i] == 0xFF && p[i + 1] == 0xFF && p[i + 2] == 0xFD && p[i + 3] == 0x00) return 1;
  }
  return 0;
}

// 0 bytes, a few, tens, or all that is left
static size_t random_chunk(uint32_t* seed, size_t left) {
  uint32_t x = next_random(seed);
  switch (x % 8) {
    case 0: return 0;
    case 1: return left;
    case 2: return (x >> 8) % 200;
    case 3: return (x >> 8) % 40;
    default: return (x >> 8) % 6 + 1;
  }
}

// Feeds data[0..n) to both readers, dxl_reader_feed_bytes in chunks of `chunk` bytes (0: random
// sizes from seed) and called again on the rest of a chunk after a result. Each call's result
// must be the byte path's on byte at + used - 1, with DXL_MORE on every byte before it, and the
// readers must then agree. Returns 1 if so; else reports the first difference and returns 0.
static int bulk_agrees(const uint8_t* data, size_t n, size_t chunk, uint32_t* seed) {
  size_t at = 0, end = 0;
  do {
    size_t len = chunk ? chunk : random_chunk(seed, n - end);
    end = end + len < n ? end + len : n;
    for (;;) {
      size_t used = (size_t)-1;
      int code = dxl_reader_feed_bytes(&g_bulk, data + at, end - at, &used);
      const char* wrong = NULL;
      g_nevents = 0;   // the byte path's results on the same bytes
      if (used > end - at) {
        wrong = "used is past the chunk";
      } else {
        feed(data + at, used);
        int event = code != DXL_MORE;
        if (event && used == 0) wrong = "a result from no byte";
        else if (!event && used != end - at) wrong = "DXL_MORE before the chunk's end";
        else if (g_nevents != event) wrong = "the byte path gives a result elsewhere";
        else if (event && g_events[0].at != g_fed - 1) wrong = "the byte path gives it earlier";
        else if (event && g_events[0].code != code) wrong = "the byte path gives another result";
        else if (!same_reader(&g_reader, &g_bulk)) wrong = "the readers differ after the call";
      }
      if (wrong) {
        sdt_context("%zu-byte stream, call on bytes %zu..%zu (chunk %zu): result %d, used %zu",
                    n, at, end, chunk, code, used);
        EXPECT_INT(0, 1, wrong);
        return 0;
      }
      at += used;
      if (code == DXL_MORE) break;
      g_bulk_codes[code + 3]++;
      if (code == DXL_PACKET && g_bulk.id == DXL_BROADCAST && g_bulk.nparam == 7 * 14 - 3) {
        g_bulk_fast++;
        g_bulk_fast_header += has_header(g_bulk.param, g_bulk.nparam);
      }
    }
  } while (end < n);
  return 1;
}

static const uint8_t k_swing_ids[7] = {1, 2, 3, 4, 5, 6, 7};
static const uint16_t k_swing_sizes[25] = {10, 10, 10, 10, 10, 10, 10, 10, 10, 10, 10, 10, 10,
                                           10, 10, 10, 10, 10, 10, 10, 10, 10, 10, 10, 10};

// the reply to a fast sync read of count servos x 10 bytes (ids 1, 2, ...), ERR then ID then
// data per servo; with header, FF FF FD 00 planted in some servos' data
static size_t swing_reply(uint8_t* out, size_t count, uint32_t* seed, int header) {
  uint8_t blocks[25 * 12];
  for (size_t k = 0; k < count; k++) {
    uint8_t* b = blocks + 12 * k;
    b[0] = next_random(seed) % 5 ? 0 : stuffable_byte(seed);
    b[1] = (uint8_t)(k + 1);
    for (int i = 0; i < 10; i++) b[2 + i] = stuffable_byte(seed);
    if (header && next_random(seed) % 2) {
      memcpy(b + 2 + next_random(seed) % 7, "\xFF\xFF\xFD\x00", 4);
    }
  }
  return fast_reply(out, blocks, k_swing_sizes, count);
}

// one piece of a bus stream: good frames of every kind, garbage, cut and corrupted frames
static size_t stream_piece(uint8_t* out, uint32_t* seed) {
  static const uint8_t garbage[6] = {0x00, 0x01, 0xFD, 0x55, 0x80, 0xFF};
  uint8_t p[DXL_MAX_PARAM + 120];
  uint32_t kind = next_random(seed) % 10;
  size_t n, np;
  switch (kind) {
    case 0:
    case 1:
      return swing_reply(out, 7, seed, kind == 1);
    case 2:   // a status packet whose params often need stuffing
      np = next_random(seed) % 40 + 1;
      for (size_t i = 0; i < np; i++) p[i] = stuffable_byte(seed);
      return dxl_packet(out, BUF, (uint8_t)(next_random(seed) % 253), DXL_STATUS, p, np);
    case 3:
      n = next_random(seed) % 12;
      for (size_t i = 0; i < n; i++) out[i] = garbage[next_random(seed) % 6];
      return n;
    case 4:   // cut short
    case 5:   // one bit of the CRC flipped
    case 6:   // one bit anywhere flipped
      if (next_random(seed) % 2) {
        n = swing_reply(out, 7, seed, 1);
      } else {
        np = next_random(seed) % 40 + 1;
        for (size_t i = 0; i < np; i++) p[i] = stuffable_byte(seed);
        n = dxl_packet(out, BUF, (uint8_t)(next_random(seed) % 253), DXL_STATUS, p, np);
      }
      if (kind == 4) return next_random(seed) % (n - 1) + 1;
      out[kind == 5 ? n - 1 - next_random(seed) % 2 : next_random(seed) % n] ^=
          (uint8_t)(1u << next_random(seed) % 8);
      return n;
    case 7:   // around DXL_MAX_PARAM: fits, too long for param, too long for LEN
      if (next_random(seed) % 2) {
        static const size_t counts[4] = {18, 19, 24, 25};
        return swing_reply(out, counts[next_random(seed) % 4], seed, 1);
      } else {
        static const int extra[6] = {0, 1, 2, 40, 87, 88};
        np = (size_t)(DXL_MAX_PARAM + extra[next_random(seed) % 6]);   // ERR and np - 1 params
        for (size_t i = 0; i < np; i++) p[i] = stuffable_byte(seed);
        return dxl_packet(out, BUF, DXL_BROADCAST, DXL_STATUS, p, np);
      }
    case 8:   // the echo of the request
      return dxl_fast_sync_read(out, BUF, 132, 10, k_swing_ids, 7);
    default:
      np = next_random(seed) % 12;
      for (size_t i = 0; i < np; i++) p[i] = stuffable_byte(seed);
      return dxl_write(out, BUF, (uint8_t)(next_random(seed) % 253), (uint16_t)next_random(seed), p,
                       (uint16_t)np);
  }
}

static void feed_bytes_equals_feed_on_random_streams(void) {
  static uint8_t stream[16 * BUF];
  uint32_t seed = 777;
  int agreed = 0, trials = 400;
  memset(g_bulk_codes, 0, sizeof g_bulk_codes);
  g_bulk_fast = g_bulk_fast_header = 0;
  for (int trial = 0; trial < trials; trial++) {
    size_t n = 0;
    for (uint32_t k = next_random(&seed) % 14 + 1; k > 0; k--) n += stream_piece(stream + n, &seed);
    start_both();
    int ok = bulk_agrees(stream, n, 0, &seed);
    agreed += ok;
    if (!ok) sdt_context("trial %d", trial);
    // every tenth stream also in chunks of each size up to 64
    for (size_t chunk = 1; ok && trial % 10 == 0 && chunk <= 64; chunk++) {
      start_both();
      ok = bulk_agrees(stream, n, chunk, &seed);
    }
    if (!ok) break;
  }
  sdt_context("%d random streams", trials);
  EXPECT_INT(agreed, trials, "dxl_reader_feed_bytes is dxl_reader_feed on every stream");
  EXPECT_GE(g_bulk_codes[DXL_PACKET + 3], 1000, "many packets");
  EXPECT_GE(g_bulk_codes[DXL_BAD_CRC + 3], 100, "many bad CRCs");
  EXPECT_GE(g_bulk_codes[DXL_TOO_LONG + 3], 100, "many frames too long");
  EXPECT_GE(g_bulk_codes[DXL_BAD_FRAME + 3], 100, "many bad frames");
  EXPECT_GE(g_bulk_fast, 500, "many whole 7 x 10 fast replies");
  EXPECT_GE(g_bulk_fast_header, 200, "many of them with a header in their data");
}

static void feed_bytes_stops_at_each_result(void) {
  uint8_t data[BUF];
  uint32_t seed = 99;
  size_t n1 = status_packet(data, 4, 0x00, "FF FF FD 00 FF FF FD");
  size_t n2 = swing_reply(data + n1, 7, &seed, 1);
  size_t n3 = dxl_ping(data + n1 + n2, BUF, 3);
  size_t used = 0;
  dxl_reader_reset(&g_bulk);
  EXPECT_INT(dxl_reader_feed_bytes(&g_bulk, data, n1 + n2 + n3, &used), DXL_PACKET, "the first");
  EXPECT_INT(used, n1, "it stops on the status packet's last byte");
  expect_bytes(g_bulk.param, g_bulk.nparam, "FF FF FD 00 FF FF FD", "its params, unstuffed");
  EXPECT_INT(dxl_reader_feed_bytes(&g_bulk, data + n1, n2 + n3, &used), DXL_PACKET, "the reply");
  EXPECT_INT(used, n2, "on its last byte: the headers in its data are data");
  dxl_block b[7];
  EXPECT_INT(dxl_fast_reply_split(&g_bulk, 10, k_swing_ids, 7, b), 7, "and it splits in 7 blocks");
  EXPECT_INT(dxl_reader_feed_bytes(&g_bulk, data + n1 + n2, n3, &used), DXL_PACKET, "the ping");
  EXPECT_INT(used, n3, "all of it");
  EXPECT_INT(dxl_reader_feed_bytes(&g_bulk, data, 0, &used), DXL_MORE, "no bytes: nothing");
  EXPECT_INT(used, 0, "none used");
  dxl_reader_reset(&g_bulk);
  EXPECT_INT(dxl_reader_feed_bytes(&g_bulk, data + n1, n2, NULL), DXL_PACKET, "used may be NULL");
  EXPECT_INT(g_bulk.nparam, 7 * 14 - 3, "the reply's params");
}

// fast replies too long for param but not for LEN (raw_run must give up and let the byte path
// refuse them on the same byte), and one too long for LEN; each followed by a ping. The servo
// counts are for DXL_MAX_PARAM 256, as built here.
static void feed_bytes_refuses_fast_replies_too_long(void) {
  static uint8_t data[4 * BUF];
  static const struct {
    size_t count, at;
    const char* why;
  } k[] = {
    {18, 0, "18 servos x 10 bytes: 249 params fit"},
    {19, 7 + 2 + DXL_MAX_PARAM, "19 servos: 263 params, refused on the 257th"},
    {24, 7 + 2 + DXL_MAX_PARAM, "24 servos: 333 params, LEN 337 still passes"},
    {25, 6, "25 servos: LEN 351, more than any frame with DXL_MAX_PARAM params; refused on LEN"},
  };
  uint8_t blocks[25 * 12];
  for (size_t i = 0; i < sizeof blocks; i++) blocks[i] = i % 12 == 1 ? (uint8_t)(i / 12 + 1) : 0x11;
  for (size_t i = 0; i < sizeof k / sizeof k[0]; i++) {
    size_t n = fast_reply(data, blocks, k_swing_sizes, k[i].count);
    size_t m = n + dxl_ping(data + n, BUF, 2);
    for (size_t chunk = 1; chunk <= m; chunk++) {
      sdt_context("%s; chunks of %zu", k[i].why, chunk);
      start_both();
      if (!bulk_agrees(data, m, chunk, NULL)) break;
    }
    sdt_context("%s", k[i].why);
    start_both();
    feed(data, m);
    const int codes[2] = {k[i].at ? DXL_TOO_LONG : DXL_PACKET, DXL_PACKET};
    expect_codes(codes, 2, "the reply, then the ping");
    if (k[i].at) EXPECT_INT(g_events[0].at, k[i].at, "on that byte");
    size_t used = 0;
    dxl_reader_reset(&g_bulk);
    EXPECT_INT(dxl_reader_feed_bytes(&g_bulk, data, m, &used), codes[0], "in one call too");
    EXPECT_INT(used, k[i].at ? k[i].at + 1 : n, "stopping on the same byte");
  }
  sdt_context("a fast reply of exactly DXL_MAX_PARAM params, then one more");
  uint8_t p[DXL_MAX_PARAM + 2];
  for (size_t i = 0; i < sizeof p; i++) p[i] = (uint8_t)"\xFF\xFF\xFD\x00"[i % 4];
  for (size_t extra = 0; extra < 2; extra++) {
    size_t n = dxl_packet(data, sizeof data, DXL_BROADCAST, DXL_STATUS, p,
                          DXL_MAX_PARAM + 1 + extra);   // ERR and the params
    size_t used = 0;
    dxl_reader_reset(&g_bulk);
    EXPECT_INT(dxl_reader_feed_bytes(&g_bulk, data, n, &used), extra ? DXL_TOO_LONG : DXL_PACKET,
               "fits, then does not");
    EXPECT_INT(used, extra ? 7 + 2 + DXL_MAX_PARAM + 1 : n,
               "the whole frame, or up to the param that does not fit");
    EXPECT_INT(same_bytes(g_bulk.param, p + 1, DXL_MAX_PARAM), 1, "the params kept, unstuffed");
  }
}

//---------------------------------- builders and fields ------------------------------------------

static void builders_refuse_small_buffers_and_bad_ids(void) {
  uint8_t out[BUF];
  const uint8_t ids[3] = {1, 2, 3}, data[9] = {0xFF, 0xFF, 0xFD, 1, 2, 3, 4, 5, 6};
  size_t full = dxl_sync_write(out, BUF, 116, 3, ids, 3, data);
  EXPECT_INT(full, 7 + 1 + 4 + 3 * 4 + 1 + 2, "sync write of 3 x 3 bytes, one stuffed byte");
  size_t refused = 0, spilled = 0;
  for (size_t cap = 0; cap < full; cap++) {
    memset(out, 0xAA, sizeof out);
    refused += dxl_sync_write(out, cap, 116, 3, ids, 3, data) == 0;
    spilled += out[cap] != 0xAA;
  }
  EXPECT_INT(refused, full, "0 for every buffer shorter than the packet");
  EXPECT_INT(spilled, 0, "and nothing written past the buffer");
  memset(out, 0xAA, sizeof out);
  EXPECT_INT(dxl_sync_write(out, full, 116, 3, ids, 3, data), full, "an exact fit is enough");
  EXPECT_INT(out[full], 0xAA, "and nothing is written past it");
  EXPECT_INT(dxl_ping(out, BUF, 0xFD), 0, "ID 0xFD does not exist");
  EXPECT_INT(dxl_ping(out, BUF, 0xFF), 0, "ID 0xFF does not exist");
  EXPECT_INT(dxl_ping(out, BUF, 0xFC), 10, "ID 252 is the largest");
  EXPECT_INT(dxl_ping(out, BUF, 0), 10, "ID 0 exists");
}

static void fields_are_little_endian(void) {
  uint8_t p[4];
  dxl_put_u32(p, 0x12345678u);
  expect_bytes(p, 4, "78 56 34 12", "least significant byte first");
  EXPECT_INT(dxl_get_u32(p), 0x12345678u, "and back");
  EXPECT_INT(dxl_get_u16(p + 2), 0x1234, "the high half");
  dxl_put_u16(p, 0xFFFF);
  EXPECT_INT(dxl_get_i16(p), -1, "FF FF is -1");
  EXPECT_INT(dxl_get_u16(p), 0xFFFF, "or 65535");
  dxl_put_u16(p, 0x8000);
  EXPECT_INT(dxl_get_i16(p), -32768, "the most negative 2-byte value");
  dxl_put_u16(p, 0x7FFF);
  EXPECT_INT(dxl_get_i16(p), 32767, "the largest");
  dxl_put_u32(p, 0xFFFFFFFDu);
  EXPECT_INT(dxl_get_i32(p), -3, "FD FF FF FF is -3");
  dxl_put_u32(p, 0x80000000u);
  EXPECT_INT(dxl_get_i32(p), -2147483647L - 1, "the most negative 4-byte value");
  dxl_put_u32(p, 0x7FFFFFFFu);
  EXPECT_INT(dxl_get_i32(p), 2147483647L, "the largest");
  EXPECT_INT(dxl_get_u32(p), 0x7FFFFFFFu, "unsigned");
}

const sdt_test sdt_dxl_tests[] = {
  {"crc_is_the_emanual_crc16", crc_is_the_emanual_crc16},
  {"emanual_instruction_packets", emanual_instruction_packets},
  {"emanual_group_packets", emanual_group_packets},
  {"emanual_status_packets", emanual_status_packets},
  {"fast_sync_reply_of_the_emanual", fast_sync_reply_of_the_emanual},
  {"fast_bulk_reply_of_the_emanual", fast_bulk_reply_of_the_emanual},
  {"fast_reply_faults_name_the_first_bad_block", fast_reply_faults_name_the_first_bad_block},
  {"fast_reply_carries_each_servos_error", fast_reply_carries_each_servos_error},
  {"fast_reply_is_never_stuffed", fast_reply_is_never_stuffed},
  {"stuffing_at_every_boundary", stuffing_at_every_boundary},
  {"status_with_present_current_minus_one", status_with_present_current_minus_one},
  {"reader_skips_garbage_before_a_packet", reader_skips_garbage_before_a_packet},
  {"reader_reports_a_bad_crc_and_goes_on", reader_reports_a_bad_crc_and_goes_on},
  {"reader_recovers_a_packet_sent_inside_a_truncated_one",
   reader_recovers_a_packet_sent_inside_a_truncated_one},
  {"reader_rejects_impossible_headers_at_once", reader_rejects_impossible_headers_at_once},
  {"reader_refuses_packets_too_long", reader_refuses_packets_too_long},
  {"reader_takes_a_header_in_the_crc_as_the_crc", reader_takes_a_header_in_the_crc_as_the_crc},
  {"reader_reset_forgets_a_partial_packet", reader_reset_forgets_a_partial_packet},
  {"reader_reads_long_random_streams", reader_reads_long_random_streams},
  {"feed_bytes_equals_feed_on_random_streams", feed_bytes_equals_feed_on_random_streams},
  {"feed_bytes_stops_at_each_result", feed_bytes_stops_at_each_result},
  {"feed_bytes_refuses_fast_replies_too_long", feed_bytes_refuses_fast_replies_too_long},
  {"builders_refuse_small_buffers_and_bad_ids", builders_refuse_small_buffers_and_bad_ids},
  {"fields_are_little_endian", fields_are_little_endian},
  {0, 0},
};
