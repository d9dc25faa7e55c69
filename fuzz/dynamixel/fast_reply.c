// fast_reply.c: libFuzzer target for the split of fast sync and bulk read replies
// (hal/dynamixel/c/dxl.c), in two ways the input's first byte chooses.
//
// Any stream: the next byte gives the block count and the sizes follow; the rest is read, and
// every packet is split with those sizes and the ids found where the blocks would put them. The
// split may refuse, but what it returns is at most the count and every block it fills lies
// inside the packet's params.
//
// A valid reply: blocks (id, error, data) drawn from the input are framed as a servo bus sends
// them (each block's CRC running over the frame so far), read, and must split to the same blocks;
// the same frame with its CRCs blanked, sealed in place (dxl_fast_reply_seal, the simulated
// servos' side), must be that frame again. In any stream, sealing the rest of the input as a
// frame of any length with those sizes writes only inside it, and only where the CRCs go.
#include "fuzz.h"

enum { MAX_BLOCKS = 16 };

// where block k's id sits in a reply of these sizes: ID0 DATA0 CRC0 ERR1 ID1 ...
static size_t id_at(const uint16_t* sizes, size_t k) {
  size_t at = 0;
  for (size_t j = 0; j < k; j++) at += 1 + sizes[j] + 3;
  return at;
}

static void check_blocks(const dxl_reader* r, int got, size_t count, const uint16_t* sizes,
                         const dxl_block* blocks) {
  CHECK(got >= 0 && (size_t)got <= count);
  for (int k = 0; k < got; k++) {
    CHECK(blocks[k].data >= r->param);
    CHECK(blocks[k].data + sizes[k] <= r->param + r->nparam);
  }
  // all blocks good: the last one ends the params (bytes after it would make it bad)
  if (got > 0 && (size_t)got == count) {
    CHECK(blocks[got - 1].data + sizes[got - 1] == r->param + r->nparam);
  }
}

// bytes k of a fast reply of these sizes that hold a block's CRC: after the header, FE, LEN and
// INST (8 bytes), per block ERR ID DATA then its CRC
static int is_crc_byte(const uint16_t* sizes, size_t count, size_t k) {
  size_t at = 8;
  for (size_t j = 0; j < count; j++) {
    at += 2u + sizes[j];
    if (k == at || k == at + 1) return 1;
    at += 2;
  }
  return 0;
}

static void any_seal(const input* in, const uint16_t* sizes, size_t count) {
  enum { ROOM = 256 };
  uint8_t frame[ROOM], before[ROOM];
  size_t n = in->n < ROOM ? in->n : ROOM;
  uint8_t* heap = malloc(n ? n : 1);     // exactly n bytes: a write past them is AddressSanitizer's
  memcpy(heap, in->p, n);
  memcpy(frame, in->p, n);
  memcpy(before, in->p, n);
  size_t end = dxl_fast_reply_seal(heap, n, sizes, count);
  CHECK(end == dxl_fast_reply_seal(frame, n, sizes, count));
  CHECK(end <= n);
  CHECK(memcmp(heap, frame, n) == 0);
  for (size_t k = 0; k < n; k++) {
    if (end == 0 || !is_crc_byte(sizes, count, k)) CHECK(heap[k] == before[k]);
  }
  free(heap);
}

static void any_stream(input* in) {
  size_t count = take(in) % (MAX_BLOCKS + 1);
  uint16_t sizes[MAX_BLOCKS], same[MAX_BLOCKS];
  for (size_t k = 0; k < count; k++) sizes[k] = take(in) % 24;
  for (size_t k = 0; k < count; k++) same[k] = count ? sizes[0] : 0;
  any_seal(in, sizes, count);
  dxl_reader r;
  dxl_reader_reset(&r);
  for (size_t i = 0; i < in->n; i++) {
    int result = dxl_reader_feed(&r, in->p[i]);
    check_reader(&r, result);
    if (result != DXL_PACKET) continue;
    uint8_t ids[MAX_BLOCKS] = {0}, same_ids[MAX_BLOCKS] = {0};
    for (size_t k = 0; k < count; k++) {
      size_t at = id_at(sizes, k), at_same = id_at(same, k);
      if (at < r.nparam) ids[k] = r.param[at];
      if (at_same < r.nparam) same_ids[k] = r.param[at_same];
    }
    dxl_block blocks[MAX_BLOCKS];
    int got = dxl_fast_bulk_reply_split(&r, sizes, ids, count, blocks);
    check_blocks(&r, got, count, sizes, blocks);
    got = dxl_fast_reply_split(&r, count ? sizes[0] : 0, same_ids, count, blocks);
    check_blocks(&r, got, count, same, blocks);
  }
}

static void valid_reply(input* in) {
  size_t count = 1 + take(in) % MAX_BLOCKS;
  uint8_t uniform = take(in) & 1;
  uint8_t ids[MAX_BLOCKS], errors[MAX_BLOCKS];
  uint16_t sizes[MAX_BLOCKS];
  size_t nparam = 0;
  for (size_t k = 0; k < count; k++) {
    ids[k] = take(in) % (DXL_MAX_ID + 1);
    errors[k] = take(in);
    sizes[k] = uniform && k ? sizes[0] : take(in) % 12;
    nparam += 1 + sizes[k] + (k + 1 < count ? 3 : 0);
  }
  if (nparam > DXL_MAX_PARAM) return;
  uint8_t frame[16 + DXL_MAX_PARAM];
  size_t n = 0;
  const uint8_t head[] = {0xFF, 0xFF, 0xFD, 0x00, DXL_BROADCAST};
  memcpy(frame, head, sizeof head);
  n = sizeof head;
  dxl_put_u16(frame + n, (uint16_t)(nparam + 4));   // INST, ERR, params, CRC
  n += 2;
  frame[n++] = DXL_STATUS;
  for (size_t k = 0; k < count; k++) {
    if (k) {
      dxl_put_u16(frame + n, dxl_crc(0, frame, n));
      n += 2;
    }
    frame[n++] = errors[k];
    frame[n++] = ids[k];
    for (size_t j = 0; j < sizes[k]; j++) frame[n++] = take(in);
  }
  dxl_put_u16(frame + n, dxl_crc(0, frame, n));
  n += 2;

  uint8_t blank[16 + DXL_MAX_PARAM];
  memcpy(blank, frame, n);
  for (size_t k = 0; k < n; k++) {
    if (is_crc_byte(sizes, count, k)) blank[k] = 0xAA;
  }
  CHECK(dxl_fast_reply_seal(blank, n, sizes, count) == n);
  CHECK(memcmp(blank, frame, n) == 0);

  dxl_reader r;
  dxl_reader_reset(&r);
  size_t used = 0;
  CHECK(dxl_reader_feed_bytes(&r, frame, n, &used) == DXL_PACKET && used == n);
  dxl_block blocks[MAX_BLOCKS];
  int got = uniform ? dxl_fast_reply_split(&r, sizes[0], ids, count, blocks)
                    : dxl_fast_bulk_reply_split(&r, sizes, ids, count, blocks);
  CHECK(got == (int)count);
  check_blocks(&r, got, count, sizes, blocks);
  size_t at = 10;   // the first block's data: header, FE, LEN, INST, ERR, ID
  for (size_t k = 0; k < count; k++) {
    CHECK(blocks[k].id == ids[k] && blocks[k].error == errors[k]);
    CHECK(memcmp(blocks[k].data, frame + at, sizes[k]) == 0);
    at += sizes[k] + 4;   // CRC, ERR, ID
  }
  // one block fewer requested: the reply has bytes after it, so that block is bad
  if (count > 1) {
    got = uniform ? dxl_fast_reply_split(&r, sizes[0], ids, count - 1, blocks)
                  : dxl_fast_bulk_reply_split(&r, sizes, ids, count - 1, blocks);
    CHECK(got == (int)count - 2);
  }
}

int LLVMFuzzerTestOneInput(const uint8_t* data, size_t n) {
  input in = {data, n};
  if (take(&in) & 1) {
    valid_reply(&in);
  } else {
    any_stream(&in);
  }
  return 0;
}
