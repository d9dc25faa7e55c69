// sts.c: see sts.h.
#include "sts.h"

#include <string.h>

static uint8_t checksum(const uint8_t* body, size_t n) {
  unsigned sum = 0;
  for (size_t k = 0; k < n; ++k) sum += body[k];
  return (uint8_t)(~sum & 0xFF);
}

size_t sts_packet(uint8_t* out, size_t cap, uint8_t id, uint8_t code, const uint8_t* param, size_t nparam) {
  size_t total = nparam + 6;
  if (id > STS_BROADCAST || nparam > STS_MAX_PARAM || total > cap) return 0;
  out[0] = 0xFF;
  out[1] = 0xFF;
  out[2] = id;
  out[3] = (uint8_t)(nparam + 2);
  out[4] = code;
  if (nparam) memcpy(out + 5, param, nparam);
  out[total - 1] = checksum(out + 2, total - 3);
  return total;
}

size_t sts_ping(uint8_t* out, size_t cap, uint8_t id) { return sts_packet(out, cap, id, STS_PING, NULL, 0); }

size_t sts_read(uint8_t* out, size_t cap, uint8_t id, uint8_t address, uint8_t size) {
  uint8_t p[2] = {address, size};
  return sts_packet(out, cap, id, STS_READ, p, 2);
}

static size_t addressed(uint8_t* out, size_t cap, uint8_t id, uint8_t code, uint8_t address, const uint8_t* data,
                        uint8_t size) {
  uint8_t p[STS_MAX_PARAM];
  if ((size_t)size + 1 > STS_MAX_PARAM) return 0;
  p[0] = address;
  if (size) memcpy(p + 1, data, size);
  return sts_packet(out, cap, id, code, p, (size_t)size + 1);
}

size_t sts_write(uint8_t* out, size_t cap, uint8_t id, uint8_t address, const uint8_t* data, uint8_t size) {
  return addressed(out, cap, id, STS_WRITE, address, data, size);
}

size_t sts_reg_write(uint8_t* out, size_t cap, uint8_t id, uint8_t address, const uint8_t* data, uint8_t size) {
  return addressed(out, cap, id, STS_REG_WRITE, address, data, size);
}

size_t sts_action(uint8_t* out, size_t cap, uint8_t id) { return sts_packet(out, cap, id, STS_ACTION, NULL, 0); }

size_t sts_sync_write(uint8_t* out, size_t cap, uint8_t address, uint8_t size, const uint8_t* ids, size_t count,
                      const uint8_t* data) {
  uint8_t p[STS_MAX_PARAM];
  size_t n = 2 + count * ((size_t)size + 1);
  if (n > STS_MAX_PARAM) return 0;
  p[0] = address;
  p[1] = size;
  for (size_t k = 0; k < count; ++k) {
    uint8_t* at = p + 2 + k * ((size_t)size + 1);
    at[0] = ids[k];
    if (size) memcpy(at + 1, data + k * size, size);
  }
  return sts_packet(out, cap, STS_BROADCAST, STS_SYNC_WRITE, p, n);
}

size_t sts_sync_read(uint8_t* out, size_t cap, uint8_t address, uint8_t size, const uint8_t* ids, size_t count) {
  uint8_t p[STS_MAX_PARAM];
  if (count + 2 > STS_MAX_PARAM) return 0;
  p[0] = address;
  p[1] = size;
  if (count) memcpy(p + 2, ids, count);
  return sts_packet(out, cap, STS_BROADCAST, STS_SYNC_READ, p, count + 2);
}

int sts_encode_sm(int32_t value, unsigned bit, uint16_t* raw) {
  int32_t magnitude = value < 0 ? -value : value;
  if (bit > 15 || magnitude >= (1L << bit)) return 0;
  *raw = (uint16_t)(value < 0 ? (magnitude | (1L << bit)) : magnitude);
  return 1;
}

int32_t sts_decode_sm(uint16_t raw, unsigned bit) {
  int32_t magnitude = raw & ((1L << bit) - 1);
  return (raw >> bit) & 1 ? -magnitude : magnitude;
}

void sts_reader_reset(sts_reader* r) { r->n = 0; }

static void drop(sts_reader* r, size_t k) {
  memmove(r->buf, r->buf + k, r->n - k);
  r->n -= k;
}

int sts_reader_feed(sts_reader* r, uint8_t byte) {
  r->buf[r->n++] = byte;
  return sts_reader_next(r);
}

// The Python reader's loop (hal/feetech/protocol.py PacketReader.feed) over the buffered bytes.
int sts_reader_next(sts_reader* r) {
  for (;;) {
    size_t start = 0;
    while (start + 1 < r->n && !(r->buf[start] == 0xFF && r->buf[start + 1] == 0xFF)) ++start;
    if (start + 1 >= r->n) {  // no header: keep a last FF, it may begin one
      size_t keep = (r->n && r->buf[r->n - 1] == 0xFF) ? 1 : 0;
      drop(r, r->n - keep);
      return STS_MORE;
    }
    while (start + 2 < r->n && r->buf[start + 2] == 0xFF) ++start;
    if (start) drop(r, start);
    if (r->n < 4) return STS_MORE;
    uint8_t len = r->buf[3];
    if (len < 2 || r->buf[2] > STS_BROADCAST) {
      drop(r, 2);
      continue;
    }
    size_t end = 4 + (size_t)len;
    if (r->n < end) return STS_MORE;
    if (checksum(r->buf + 2, end - 3) != r->buf[end - 1]) {
      drop(r, 2);
      continue;
    }
    r->id = r->buf[2];
    r->code = r->buf[4];
    r->nparam = (uint8_t)(len - 2);
    memcpy(r->param, r->buf + 5, r->nparam);
    drop(r, end);
    return STS_PACKET;
  }
}
