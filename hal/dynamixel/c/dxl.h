// dxl.h: DYNAMIXEL Protocol 2.0 codec for the firmware: instruction packets out, status packets in.
//
// Written from the ROBOTIS e-manual, "DYNAMIXEL Protocol 2.0"; it agrees byte for byte with the
// Python codec (hal/dynamixel/protocol.py, instructions.py, reader.py), tests/test_dxl_c.py checks.
// A frame is  FF FF FD 00 | ID | LEN_L LEN_H | INST | params | CRC_L CRC_H,  LEN counting INST,
// the stuffed params and the CRC. No heap, no stdio, no floating point: builders write into the
// caller's buffer, and the reader takes one byte at a time in constant work (an ISR can feed it).
#ifndef DXL_H
#define DXL_H

#include <stddef.h>
#include <stdint.h>

// The largest unstuffed parameter block the reader keeps (a status packet's params after ERR).
// It sizes dxl_reader, so every file that includes this header must see the same value.
#ifndef DXL_MAX_PARAM
#define DXL_MAX_PARAM 256
#endif

enum { DXL_BROADCAST = 0xFE, DXL_MAX_ID = 0xFC };

enum dxl_instruction_ {
  DXL_PING = 0x01,
  DXL_READ = 0x02,
  DXL_WRITE = 0x03,
  DXL_REG_WRITE = 0x04,
  DXL_ACTION = 0x05,
  DXL_FACTORY_RESET = 0x06,
  DXL_REBOOT = 0x08,
  DXL_CLEAR = 0x10,
  DXL_STATUS = 0x55,
  DXL_SYNC_READ = 0x82,
  DXL_SYNC_WRITE = 0x83,
  DXL_FAST_SYNC_READ = 0x8A,
  DXL_BULK_READ = 0x92,
  DXL_BULK_WRITE = 0x93,
  DXL_FAST_BULK_READ = 0x9A
};

// CRC-16 of the e-manual (poly 0x8005, init 0, MSB first, no reflection), continuing from crc.
uint16_t dxl_crc(uint16_t crc, const uint8_t* data, size_t n);
// The same, one byte, inline: a table lookup (the CRC of each byte value, 512 bytes of flash)
extern const uint16_t dxl_crc_table[256];
static inline uint16_t dxl_crc_byte(uint16_t crc, uint8_t byte) {
  return (uint16_t)((uint16_t)(crc << 8) ^ dxl_crc_table[((crc >> 8) ^ byte) & 0xFF]);
}

//---------------------------------- instruction packets ------------------------------------------
// Every builder writes one complete frame to out and returns its length in bytes, or 0 (out then
// undefined) when it does not fit in cap or id is not 0..252 or 254 (broadcast). INST and params
// are byte-stuffed (FF FF FD -> FF FF FD FD); LEN and CRC cover the stuffed bytes. A status packet
// from 0xFE (a fast read reply) is the one frame sent unstuffed, as on the Python side.

size_t dxl_packet(uint8_t* out, size_t cap, uint8_t id, uint8_t instruction, const uint8_t* param,
                  size_t nparam);
size_t dxl_ping(uint8_t* out, size_t cap, uint8_t id);
size_t dxl_read(uint8_t* out, size_t cap, uint8_t id, uint16_t address, uint16_t size);
size_t dxl_write(uint8_t* out, size_t cap, uint8_t id, uint16_t address, const uint8_t* data,
                 uint16_t size);
size_t dxl_reboot(uint8_t* out, size_t cap, uint8_t id);
// data: count * size bytes, servo k's little-endian register bytes at data + k * size
size_t dxl_sync_write(uint8_t* out, size_t cap, uint16_t address, uint16_t size,
                      const uint8_t* ids, size_t count, const uint8_t* data);
size_t dxl_sync_read(uint8_t* out, size_t cap, uint16_t address, uint16_t size, const uint8_t* ids,
                     size_t count);
size_t dxl_fast_sync_read(uint8_t* out, size_t cap, uint16_t address, uint16_t size,
                          const uint8_t* ids, size_t count);
// servo k reads size[k] bytes from address[k]
size_t dxl_bulk_read(uint8_t* out, size_t cap, const uint8_t* ids, const uint16_t* address,
                     const uint16_t* size, size_t count);
size_t dxl_fast_bulk_read(uint8_t* out, size_t cap, const uint8_t* ids, const uint16_t* address,
                          const uint16_t* size, size_t count);

//---------------------------------- little-endian fields -----------------------------------------

// inline: every register value and every field of the host link goes through them, in the tick

static inline void dxl_put_u16(uint8_t* p, uint16_t v) {
  p[0] = (uint8_t)v;
  p[1] = (uint8_t)(v >> 8);
}

static inline void dxl_put_u32(uint8_t* p, uint32_t v) {
  dxl_put_u16(p, (uint16_t)v);
  dxl_put_u16(p + 2, (uint16_t)(v >> 16));
}

static inline uint16_t dxl_get_u16(const uint8_t* p) {
  return (uint16_t)(p[0] | p[1] << 8);
}

static inline uint32_t dxl_get_u32(const uint8_t* p) {
  return (uint32_t)dxl_get_u16(p) | (uint32_t)dxl_get_u16(p + 2) << 16;
}

// two's complement by value, not by a cast of an out-of-range unsigned (implementation-defined)
static inline int16_t dxl_get_i16(const uint8_t* p) {
  uint16_t u = dxl_get_u16(p);
  return u < 0x8000u ? (int16_t)u : (int16_t)(-(int32_t)(0x10000u - u));
}

static inline int32_t dxl_get_i32(const uint8_t* p) {
  uint32_t u = dxl_get_u32(p);
  return u < 0x80000000u ? (int32_t)u : -(int32_t)(0xFFFFFFFFu - u) - 1;
}

//---------------------------------- the reader ---------------------------------------------------
// Feed the received bytes one at a time. It finds the header after any garbage, checks ID, LEN
// and CRC (over the stuffed bytes), removes the stuffing and returns DXL_PACKET on the last byte
// of a good frame; id, instruction, error and param then hold it until the next byte is fed.
// Any frame is read, so the echo of an instruction packet on a half-duplex line comes out as a
// packet with that instruction, error 0 and every byte after INST in param: check instruction.
//
// A header inside a stuffed frame cannot be data, so it abandons that frame (DXL_BAD_FRAME) and
// starts the new one: a packet that follows a truncated one is not lost. A fast read reply is
// unstuffed, so a header inside it is data; after a bad one the reader searches from its end.
// The e-manual drops a frame after 1.5 ms of silence between bytes: the caller owns the clock and
// calls dxl_reader_reset then (and before a new request, to forget a half-received answer).

enum dxl_feed_ {
  DXL_MORE = 0,        // nothing complete yet
  DXL_PACKET = 1,      // a good frame is complete
  DXL_BAD_CRC = -1,    // a complete frame whose CRC does not match
  DXL_TOO_LONG = -2,   // a frame whose params do not fit DXL_MAX_PARAM
  DXL_BAD_FRAME = -3   // impossible ID or LEN, a status packet without ERR, or a frame cut short
};

typedef struct dxl_reader_ {
  uint32_t window;      // the last four bytes received, to spot a header anywhere
  uint32_t tail;        // the last body bytes received, to spot the stuffing
  uint16_t crc;         // CRC of the frame so far
  uint16_t remain;      // body bytes (INST and stuffed params) still to come
  uint8_t state;
  uint8_t nbody;        // unstuffed body bytes so far, counted up to 2 (INST, ERR)
  uint8_t raw;          // 1 in a fast read reply, which is not stuffed
  uint8_t crc_low;
  uint8_t id;
  uint8_t instruction;
  uint8_t error;                  // a status packet's ERR byte; 0 for other packets
  uint16_t nparam;
  uint8_t param[DXL_MAX_PARAM];   // after the error byte, destuffed
} dxl_reader;

void dxl_reader_reset(dxl_reader* r);
int dxl_reader_feed(dxl_reader* r, uint8_t byte);
// Feed up to n bytes, as many dxl_reader_feed calls, stopping at the first result other than
// DXL_MORE (returned); *used (may be NULL) gets the bytes taken. The params of a fast read reply
// go through a fast path: copied and CRC-folded without the per-byte state machine.
int dxl_reader_feed_bytes(dxl_reader* r, const uint8_t* data, size_t n, size_t* used);

//---------------------------------- fast read replies --------------------------------------------
// A fast sync or bulk read is answered by one status packet from ID 0xFE, unstuffed: per servo in
// request order ERR ID DATA CRC(2), where each block's CRC is the CRC of the whole frame up to it
// (header and earlier blocks' CRCs included). The first ERR is the packet's ERR byte and the last
// CRC is the packet's CRC, so param holds  ID0 DATA0 CRC0  ERR1 ID1 DATA1 CRC1 ... ERRn IDn DATAn.
//
// The split checks that r holds a status packet from 0xFE carrying exactly count blocks with the
// ids in order and good running CRCs, and fills blocks[k] (data points into r->param). It returns
// count when all are good, otherwise the index of the first block that is missing, cut short,
// from another id or fails its CRC (blocks before it are filled and good); the last block is bad
// when bytes follow it. A reply that ends early after whole blocks returns how many came.

typedef struct dxl_block_ {
  uint8_t id;
  uint8_t error;
  const uint8_t* data;
} dxl_block;

int dxl_fast_reply_split(const dxl_reader* r, uint16_t size, const uint8_t* ids, size_t count,
                         dxl_block* blocks);
// the reply to dxl_fast_bulk_read: block k has size[k] data bytes
int dxl_fast_bulk_reply_split(const dxl_reader* r, const uint16_t* size, const uint8_t* ids,
                              size_t count, dxl_block* blocks);

// The servos' side: a fast read reply laid out in frame (n bytes: header, FE, LEN, INST, then
// per block ERR ID DATA and two bytes for its CRC, block k with size[k] data bytes) gets the
// running CRC of each of its first count blocks written in place. Returns the bytes up to the
// last CRC written, or 0 (frame untouched) when the blocks do not fit in n.
size_t dxl_fast_reply_seal(uint8_t* frame, size_t n, const uint16_t* size, size_t count);

#endif  // DXL_H
