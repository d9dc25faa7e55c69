// sts.h: Feetech STS/SMS codec (FT-SCS protocol, Protocol 1.0 framing) for the firmware:
// instruction packets out, status packets in, the sign-magnitude fields.
//
// It agrees byte for byte with the Python codec (hal/feetech/protocol.py), which is tested against
// Feetech's own SDK; tests/test_feetech.py checks the two against each other. A frame is
//   FF FF | ID | LEN | INST or ERR | params | CHK,   LEN = nparams + 2,
//   CHK = ~(ID + LEN + INST + sum(params)) & 0xFF.
// No heap, no stdio, no floating point: builders write into the caller's buffer.
#ifndef STS_H
#define STS_H

#include <stddef.h>
#include <stdint.h>

enum { STS_BROADCAST = 0xFE, STS_MAX_PARAM = 250 };

enum sts_instruction_ {
  STS_PING = 0x01,
  STS_READ = 0x02,
  STS_WRITE = 0x03,
  STS_REG_WRITE = 0x04,
  STS_ACTION = 0x05,
  STS_SYNC_READ = 0x82,
  STS_SYNC_WRITE = 0x83
};

//---------------------------------- instruction packets ------------------------------------------
// Each builder writes one frame to out and returns its length, or 0 when it does not fit in cap,
// id is above 0xFE or the parameters exceed STS_MAX_PARAM.
size_t sts_packet(uint8_t* out, size_t cap, uint8_t id, uint8_t code, const uint8_t* param, size_t nparam);
size_t sts_ping(uint8_t* out, size_t cap, uint8_t id);
size_t sts_read(uint8_t* out, size_t cap, uint8_t id, uint8_t address, uint8_t size);
size_t sts_write(uint8_t* out, size_t cap, uint8_t id, uint8_t address, const uint8_t* data, uint8_t size);
size_t sts_reg_write(uint8_t* out, size_t cap, uint8_t id, uint8_t address, const uint8_t* data, uint8_t size);
size_t sts_action(uint8_t* out, size_t cap, uint8_t id);
// data: count * size bytes, servo k's register bytes at data + k * size
size_t sts_sync_write(uint8_t* out, size_t cap, uint8_t address, uint8_t size, const uint8_t* ids, size_t count,
                      const uint8_t* data);
size_t sts_sync_read(uint8_t* out, size_t cap, uint8_t address, uint8_t size, const uint8_t* ids, size_t count);

//---------------------------------- sign-magnitude fields ----------------------------------------
// The raw register value of `value` with its sign in bit `bit` (15 position and speed, 11 homing
// offset, 10 PWM goal and load): 1 and *raw set, or 0 when |value| does not fit below the bit.
int sts_encode_sm(int32_t value, unsigned bit, uint16_t* raw);
// The value of a raw register; bits above the sign bit are dropped.
int32_t sts_decode_sm(uint16_t raw, unsigned bit);

//---------------------------------- the reader ---------------------------------------------------
// Feed the received bytes one at a time; it returns STS_PACKET on the byte that completes a packet
// whose checksum matches (its fields are then in the reader until the next byte), STS_MORE
// otherwise. Garbage, an impossible ID or LEN and a bad checksum are skipped, and the search goes
// on from the byte after the bad header's first, so a packet inside a broken frame is still found:
// the same packets, in the same order, as the Python reader's.
enum { STS_MORE = 0, STS_PACKET = 1 };

typedef struct {
  uint8_t buf[4 + 255];
  size_t n;
  uint8_t id, code, nparam;
  uint8_t param[STS_MAX_PARAM + 3];
} sts_reader;

void sts_reader_reset(sts_reader* r);
int sts_reader_feed(sts_reader* r, uint8_t byte);
// After a packet: the next one already whole in the buffer (a broken frame's rescan can leave one),
// STS_PACKET, or STS_MORE. Call it until STS_MORE before feeding the next byte.
int sts_reader_next(sts_reader* r);

#endif
