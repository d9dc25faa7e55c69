// dxl.c: DYNAMIXEL Protocol 2.0 codec (dxl.h): CRC, stuffing builders, byte-at-a-time reader and
// the fast read reply split. Everything mirrors the Python codec in hal/dynamixel/.
#include "dxl.h"

//---------------------------------- CRC-16 -------------------------------------------------------

// CRC of each byte value for poly 0x8005 (table-driven: one lookup per byte, 512 bytes of flash)
const uint16_t dxl_crc_table[256] = {
    0x0000, 0x8005, 0x800F, 0x000A, 0x801B, 0x001E, 0x0014, 0x8011,
    0x8033, 0x0036, 0x003C, 0x8039, 0x0028, 0x802D, 0x8027, 0x0022,
    0x8063, 0x0066, 0x006C, 0x8069, 0x0078, 0x807D, 0x8077, 0x0072,
    0x0050, 0x8055, 0x805F, 0x005A, 0x804B, 0x004E, 0x0044, 0x8041,
    0x80C3, 0x00C6, 0x00CC, 0x80C9, 0x00D8, 0x80DD, 0x80D7, 0x00D2,
    0x00F0, 0x80F5, 0x80FF, 0x00FA, 0x80EB, 0x00EE, 0x00E4, 0x80E1,
    0x00A0, 0x80A5, 0x80AF, 0x00AA, 0x80BB, 0x00BE, 0x00B4, 0x80B1,
    0x8093, 0x0096, 0x009C, 0x8099, 0x0088, 0x808D, 0x8087, 0x0082,
    0x8183, 0x0186, 0x018C, 0x8189, 0x0198, 0x819D, 0x8197, 0x0192,
    0x01B0, 0x81B5, 0x81BF, 0x01BA, 0x81AB, 0x01AE, 0x01A4, 0x81A1,
    0x01E0, 0x81E5, 0x81EF, 0x01EA, 0x81FB, 0x01FE, 0x01F4, 0x81F1,
    0x81D3, 0x01D6, 0x01DC, 0x81D9, 0x01C8, 0x81CD, 0x81C7, 0x01C2,
    0x0140, 0x8145, 0x814F, 0x014A, 0x815B, 0x015E, 0x0154, 0x8151,
    0x8173, 0x0176, 0x017C, 0x8179, 0x0168, 0x816D, 0x8167, 0x0162,
    0x8123, 0x0126, 0x012C, 0x8129, 0x0138, 0x813D, 0x8137, 0x0132,
    0x0110, 0x8115, 0x811F, 0x011A, 0x810B, 0x010E, 0x0104, 0x8101,
    0x8303, 0x0306, 0x030C, 0x8309, 0x0318, 0x831D, 0x8317, 0x0312,
    0x0330, 0x8335, 0x833F, 0x033A, 0x832B, 0x032E, 0x0324, 0x8321,
    0x0360, 0x8365, 0x836F, 0x036A, 0x837B, 0x037E, 0x0374, 0x8371,
    0x8353, 0x0356, 0x035C, 0x8359, 0x0348, 0x834D, 0x8347, 0x0342,
    0x03C0, 0x83C5, 0x83CF, 0x03CA, 0x83DB, 0x03DE, 0x03D4, 0x83D1,
    0x83F3, 0x03F6, 0x03FC, 0x83F9, 0x03E8, 0x83ED, 0x83E7, 0x03E2,
    0x83A3, 0x03A6, 0x03AC, 0x83A9, 0x03B8, 0x83BD, 0x83B7, 0x03B2,
    0x0390, 0x8395, 0x839F, 0x039A, 0x838B, 0x038E, 0x0384, 0x8381,
    0x0280, 0x8285, 0x828F, 0x028A, 0x829B, 0x029E, 0x0294, 0x8291,
    0x82B3, 0x02B6, 0x02BC, 0x82B9, 0x02A8, 0x82AD, 0x82A7, 0x02A2,
    0x82E3, 0x02E6, 0x02EC, 0x82E9, 0x02F8, 0x82FD, 0x82F7, 0x02F2,
    0x02D0, 0x82D5, 0x82DF, 0x02DA, 0x82CB, 0x02CE, 0x02C4, 0x82C1,
    0x8243, 0x0246, 0x024C, 0x8249, 0x0258, 0x825D, 0x8257, 0x0252,
    0x0270, 0x8275, 0x827F, 0x027A, 0x826B, 0x026E, 0x0264, 0x8261,
    0x0220, 0x8225, 0x822F, 0x022A, 0x823B, 0x023E, 0x0234, 0x8231,
    0x8213, 0x0216, 0x021C, 0x8219, 0x0208, 0x820D, 0x8207, 0x0202,
};

uint16_t dxl_crc(uint16_t crc, const uint8_t* data, size_t n) {
  for (size_t i = 0; i < n; i++) {
    crc = dxl_crc_byte(crc, data[i]);
  }
  return crc;
}

//---------------------------------- instruction packets ------------------------------------------

enum {
  HEADER_SIZE = 4,
  HEAD_SIZE = 7,   // header, ID, LEN: the bytes LEN does not count
  MIN_LENGTH = 3   // INST + CRC
};
static const uint8_t header[HEADER_SIZE] = {0xFF, 0xFF, 0xFD, 0x00};

static int valid_id(uint8_t id) {
  return id <= DXL_MAX_ID || id == DXL_BROADCAST;
}

// A frame under construction. n counts every byte, also those past cap, so that builders write
// without checking and finish() alone decides whether the frame fit.
typedef struct writer_ {
  uint8_t* out;
  size_t cap;
  size_t n;
  uint32_t tail;   // the body bytes since the last stuffing, to spot FF FF FD
  int stuff;
} writer;

static void emit(writer* w, uint8_t byte) {
  if (w->n < w->cap) w->out[w->n] = byte;
  w->n++;
}

// a body byte (INST or parameter): FD goes in after every FF FF FD, and the search for the next
// one restarts after it, which is the e-manual's rule (the pattern cannot overlap itself)
static void body(writer* w, uint8_t byte) {
  emit(w, byte);
  w->tail = w->tail << 8 | byte;
  if (w->stuff && (w->tail & 0xFFFFFFu) == 0xFFFFFDu) {
    emit(w, 0xFD);
    w->tail = 0;
  }
}

static void body_u16(writer* w, uint16_t v) {
  body(w, (uint8_t)v);
  body(w, (uint8_t)(v >> 8));
}

static void body_bytes(writer* w, const uint8_t* p, size_t n) {
  for (size_t i = 0; i < n; i++) body(w, p[i]);
}

static void begin(writer* w, uint8_t* out, size_t cap, uint8_t id, uint8_t instruction) {
  w->out = out;
  w->cap = cap;
  w->n = 0;
  w->tail = 0;
  // a fast read reply (status from 0xFE) goes out unstuffed, as the Python side sends it
  w->stuff = !(id == DXL_BROADCAST && instruction == DXL_STATUS);
  for (int i = 0; i < HEADER_SIZE; i++) emit(w, header[i]);
  emit(w, id);
  emit(w, 0);   // LEN, known at the end
  emit(w, 0);
  body(w, instruction);
}

// LEN and CRC cover the stuffed body, so both are written last
static size_t finish(writer* w) {
  size_t length = w->n - HEAD_SIZE + 2;
  if (w->n + 2 > w->cap || length > 0xFFFF || !valid_id(w->out[4])) return 0;
  dxl_put_u16(w->out + 5, (uint16_t)length);
  uint16_t crc = dxl_crc(0, w->out, w->n);
  emit(w, (uint8_t)crc);
  emit(w, (uint8_t)(crc >> 8));
  return w->n;
}

size_t dxl_packet(uint8_t* out, size_t cap, uint8_t id, uint8_t instruction, const uint8_t* param,
                  size_t nparam) {
  writer w;
  begin(&w, out, cap, id, instruction);
  body_bytes(&w, param, nparam);
  return finish(&w);
}

size_t dxl_ping(uint8_t* out, size_t cap, uint8_t id) {
  return dxl_packet(out, cap, id, DXL_PING, NULL, 0);
}

size_t dxl_reboot(uint8_t* out, size_t cap, uint8_t id) {
  return dxl_packet(out, cap, id, DXL_REBOOT, NULL, 0);
}

size_t dxl_read(uint8_t* out, size_t cap, uint8_t id, uint16_t address, uint16_t size) {
  writer w;
  begin(&w, out, cap, id, DXL_READ);
  body_u16(&w, address);
  body_u16(&w, size);
  return finish(&w);
}

size_t dxl_write(uint8_t* out, size_t cap, uint8_t id, uint16_t address, const uint8_t* data,
                 uint16_t size) {
  writer w;
  begin(&w, out, cap, id, DXL_WRITE);
  body_u16(&w, address);
  body_bytes(&w, data, size);
  return finish(&w);
}

size_t dxl_sync_write(uint8_t* out, size_t cap, uint16_t address, uint16_t size,
                      const uint8_t* ids, size_t count, const uint8_t* data) {
  writer w;
  begin(&w, out, cap, DXL_BROADCAST, DXL_SYNC_WRITE);
  body_u16(&w, address);
  body_u16(&w, size);
  for (size_t k = 0; k < count; k++) {
    body(&w, ids[k]);
    body_bytes(&w, data + k * size, size);
  }
  return finish(&w);
}

static size_t sync_read(uint8_t* out, size_t cap, uint8_t instruction, uint16_t address,
                        uint16_t size, const uint8_t* ids, size_t count) {
  writer w;
  begin(&w, out, cap, DXL_BROADCAST, instruction);
  body_u16(&w, address);
  body_u16(&w, size);
  body_bytes(&w, ids, count);
  return finish(&w);
}

size_t dxl_sync_read(uint8_t* out, size_t cap, uint16_t address, uint16_t size, const uint8_t* ids,
                     size_t count) {
  return sync_read(out, cap, DXL_SYNC_READ, address, size, ids, count);
}

size_t dxl_fast_sync_read(uint8_t* out, size_t cap, uint16_t address, uint16_t size,
                          const uint8_t* ids, size_t count) {
  return sync_read(out, cap, DXL_FAST_SYNC_READ, address, size, ids, count);
}

static size_t bulk_read(uint8_t* out, size_t cap, uint8_t instruction, const uint8_t* ids,
                        const uint16_t* address, const uint16_t* size, size_t count) {
  writer w;
  begin(&w, out, cap, DXL_BROADCAST, instruction);
  for (size_t k = 0; k < count; k++) {
    body(&w, ids[k]);
    body_u16(&w, address[k]);
    body_u16(&w, size[k]);
  }
  return finish(&w);
}

size_t dxl_bulk_read(uint8_t* out, size_t cap, const uint8_t* ids, const uint16_t* address,
                     const uint16_t* size, size_t count) {
  return bulk_read(out, cap, DXL_BULK_READ, ids, address, size, count);
}

size_t dxl_fast_bulk_read(uint8_t* out, size_t cap, const uint8_t* ids, const uint16_t* address,
                          const uint16_t* size, size_t count) {
  return bulk_read(out, cap, DXL_FAST_BULK_READ, ids, address, size, count);
}

//---------------------------------- the reader ---------------------------------------------------

enum { ST_SEARCH = 0, ST_ID, ST_LEN_L, ST_LEN_H, ST_BODY, ST_CRC_L, ST_CRC_H };

#define HEADER_WORD 0xFFFFFD00u
// LEN - 2 of the largest frame whose params can fit: INST, ERR and DXL_MAX_PARAM bytes, with the
// most stuffing they can carry (one FD per three bytes); a longer LEN is refused at once
#define MAX_BODY ((uint32_t)(DXL_MAX_PARAM + 2) + (uint32_t)(DXL_MAX_PARAM + 2) / 3)

static int fail(dxl_reader* r, int result) {
  r->state = ST_SEARCH;
  return result;
}

void dxl_reader_reset(dxl_reader* r) {
  r->state = ST_SEARCH;
  r->window = 0;
  r->nparam = 0;
}

static void start_frame(dxl_reader* r) {
  r->state = ST_ID;
  r->crc = dxl_crc(0, header, HEADER_SIZE);
  r->tail = 0;
  r->nbody = 0;
  r->raw = 0;
  r->instruction = 0;
  r->error = 0;
  r->nparam = 0;
}

static int on_id(dxl_reader* r, uint8_t byte) {
  if (!valid_id(byte)) return fail(r, DXL_BAD_FRAME);
  r->id = byte;
  r->state = ST_LEN_L;
  return DXL_MORE;
}

static int on_length(dxl_reader* r, uint8_t high) {
  uint32_t length = r->remain | (uint32_t)high << 8;
  if (length < MIN_LENGTH) return fail(r, DXL_BAD_FRAME);
  if (length - 2 > MAX_BODY) return fail(r, DXL_TOO_LONG);
  r->remain = (uint16_t)(length - 2);
  r->state = ST_BODY;
  return DXL_MORE;
}

// one unstuffed body byte: INST, then ERR if it is a status packet, then the params
static int keep(dxl_reader* r, uint8_t byte) {
  if (r->nbody == 0) {
    r->instruction = byte;
    r->raw = r->id == DXL_BROADCAST && byte == DXL_STATUS;
    r->nbody = 1;
  } else if (r->nbody == 1 && r->instruction == DXL_STATUS) {
    r->error = byte;
    r->nbody = 2;
  } else {
    if (r->nparam == DXL_MAX_PARAM) return 0;
    r->param[r->nparam++] = byte;
  }
  return 1;
}

// the FD of FF FF FD FD is dropped, and the search restarts after it, as stuffing inserted it
static int on_body(dxl_reader* r, uint8_t byte) {
  int stuffing = !r->raw && (r->tail & 0xFFFFFFu) == 0xFFFFFDu && byte == 0xFD;
  r->tail = stuffing ? 0 : r->tail << 8 | byte;
  if (!stuffing && !keep(r, byte)) return fail(r, DXL_TOO_LONG);
  if (--r->remain == 0) r->state = ST_CRC_L;
  return DXL_MORE;
}

static int on_crc(dxl_reader* r, uint8_t high) {
  r->state = ST_SEARCH;
  if ((uint16_t)(r->crc_low | high << 8) != r->crc) return DXL_BAD_CRC;
  // the frame is consumed whole: none of its bytes may begin the next header
  r->window = 0;
  if (r->instruction == DXL_STATUS && r->nbody < 2) return DXL_BAD_FRAME;
  return DXL_PACKET;
}

static int step(dxl_reader* r, uint8_t byte) {
  if (r->state < ST_CRC_L) r->crc = dxl_crc_byte(r->crc, byte);
  switch (r->state) {
    case ST_ID:
      return on_id(r, byte);
    case ST_LEN_L:
      r->remain = byte;
      r->state = ST_LEN_H;
      return DXL_MORE;
    case ST_LEN_H:
      return on_length(r, byte);
    case ST_BODY:
      return on_body(r, byte);
    case ST_CRC_L:
      r->crc_low = byte;
      r->state = ST_CRC_H;
      return DXL_MORE;
    default:
      return on_crc(r, byte);
  }
}

// Stuffing keeps FF FF FD 00 out of a body, and an ID or LEN that could take part in one is
// refused, so a header ending before a stuffed frame's last byte means the frame was cut short
// and a new one began. (Ending on the last byte, its CRC bytes may be FD 00: on_crc decides.)
static int cut_short(const dxl_reader* r) {
  return r->window == HEADER_WORD && !r->raw && (r->state == ST_BODY || r->state == ST_CRC_L);
}

int dxl_reader_feed(dxl_reader* r, uint8_t byte) {
  r->window = r->window << 8 | byte;
  int result = DXL_MORE;
  if (r->state != ST_SEARCH) result = cut_short(r) ? fail(r, DXL_BAD_FRAME) : step(r, byte);
  if (r->state == ST_SEARCH && r->window == HEADER_WORD) start_frame(r);
  return result;
}

// The bytes of a fast read reply's params need no stuffing check and no header search (a header
// inside one is data): they are copied and folded into the CRC in one tight loop, which is what
// makes a 100-byte reply cheap enough for a control tick on a microcontroller.
static size_t raw_run(dxl_reader* r, const uint8_t* data, size_t n) {
  size_t run = n < r->remain ? n : r->remain;
  if (run > (size_t)(DXL_MAX_PARAM - r->nparam)) return 0;
  uint16_t crc = r->crc;
  uint8_t* out = r->param + r->nparam;
  for (size_t i = 0; i < run; i++) {
    crc = dxl_crc_byte(crc, data[i]);
    out[i] = data[i];
  }
  r->crc = crc;
  r->nparam = (uint16_t)(r->nparam + run);
  r->remain = (uint16_t)(r->remain - run);
  for (size_t i = run > 4 ? run - 4 : 0; i < run; i++) r->window = r->window << 8 | data[i];
  r->tail = 0;
  if (r->remain == 0) r->state = ST_CRC_L;
  return run;
}

int dxl_reader_feed_bytes(dxl_reader* r, const uint8_t* data, size_t n, size_t* used) {
  size_t i = 0;
  int result = DXL_MORE;
  while (i < n && result == DXL_MORE) {
    size_t run = 0;
    if (r->raw && r->state == ST_BODY && r->nbody >= 2) run = raw_run(r, data + i, n - i);
    if (run) {
      i += run;
    } else {
      result = dxl_reader_feed(r, data[i++]);
    }
  }
  if (used) *used = i;
  return result;
}

//---------------------------------- fast read replies --------------------------------------------

// CRC of the reply's frame up to its params: header, FE, LEN, INST, ERR (never stuffed)
static uint16_t reply_crc_start(const dxl_reader* r) {
  uint8_t head[HEAD_SIZE + 2] = {0xFF, 0xFF, 0xFD, 0x00, DXL_BROADCAST, 0, 0, DXL_STATUS, r->error};
  dxl_put_u16(head + 5, (uint16_t)(r->nparam + 4));   // INST, ERR, params, CRC
  return dxl_crc(0, head, sizeof head);
}

// size: each block's data size, or sizes[k] when sizes is not NULL
static int split(const dxl_reader* r, const uint16_t* sizes, uint16_t size, const uint8_t* ids,
                 size_t count, dxl_block* blocks) {
  if (r->id != DXL_BROADCAST || r->instruction != DXL_STATUS) return 0;
  const uint8_t* p = r->param;
  uint16_t crc = reply_crc_start(r);
  size_t at = 0;   // where block k begins in param: its ERR, or the ID of the first block
  for (size_t k = 0; k < count; k++) {
    size_t id_at = k ? at + 1 : 0;
    size_t end = id_at + 1 + (sizes ? sizes[k] : size);   // one past its data
    if (end > r->nparam || p[id_at] != ids[k]) return (int)k;
    crc = dxl_crc(crc, p + at, end - at);
    int last_in_packet = end == r->nparam;   // then its CRC was the packet's, already checked
    if (!last_in_packet && (k + 1 == count || end + 2 > r->nparam || dxl_get_u16(p + end) != crc)) {
      return (int)k;
    }
    blocks[k].id = ids[k];
    blocks[k].error = k ? p[at] : r->error;
    blocks[k].data = p + id_at + 1;
    if (last_in_packet) return (int)(k + 1);
    crc = dxl_crc(crc, p + end, 2);
    at = end + 2;
  }
  return (int)count;
}

int dxl_fast_reply_split(const dxl_reader* r, uint16_t size, const uint8_t* ids, size_t count,
                         dxl_block* blocks) {
  return split(r, NULL, size, ids, count, blocks);
}

int dxl_fast_bulk_reply_split(const dxl_reader* r, const uint16_t* size, const uint8_t* ids,
                              size_t count, dxl_block* blocks) {
  return split(r, size, 0, ids, count, blocks);
}

size_t dxl_fast_reply_seal(uint8_t* frame, size_t n, const uint16_t* size, size_t count) {
  size_t end = HEAD_SIZE + 1;   // the first block's ERR, after INST
  if (end > n) return 0;        // not even the header: no reply of any blocks fits
  for (size_t k = 0; k < count; k++) {
    end += 2u + size[k];         // its CRC
    if (end + 2 > n) return 0;
    end += 2;                    // the next block's ERR
  }
  uint16_t crc = 0;
  size_t begin = 0;
  end = HEAD_SIZE + 1;
  for (size_t k = 0; k < count; k++) {
    end += 2u + size[k];
    crc = dxl_crc(crc, frame + begin, end - begin);
    dxl_put_u16(frame + end, crc);
    begin = end;
    end += 2;
  }
  return end;
}
