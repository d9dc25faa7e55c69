// reader.c: libFuzzer target for the Dynamixel reader (hal/dynamixel/c/dxl.c), any byte stream.
//
// Two readers take the same bytes: one byte by byte (dxl_reader_feed), the other in chunks whose
// sizes the input's first byte draws (dxl_reader_feed_bytes, with its fast path for fast read
// replies). They must give the same results at the same bytes and the same packets. Each packet
// is built again with dxl_packet (stuffed as a sender must) and read back to the same fields.
#include "fuzz.h"

enum { MAX_FRAME = 2 * DXL_MAX_PARAM + 32 };

// a packet read back from its own encoding
static void round_trip(const dxl_reader* r) {
  uint8_t params[DXL_MAX_PARAM + 1];
  size_t n = 0;
  if (r->instruction == DXL_STATUS) params[n++] = r->error;
  memcpy(params + n, r->param, r->nparam);
  n += r->nparam;
  uint8_t frame[MAX_FRAME];
  size_t len = dxl_packet(frame, sizeof frame, r->id, r->instruction, params, n);
  CHECK(len > 0);
  dxl_reader again;
  dxl_reader_reset(&again);
  for (size_t i = 0; i < len; i++) {
    int result = dxl_reader_feed(&again, frame[i]);
    check_reader(&again, result);
    CHECK(result == (i + 1 == len ? DXL_PACKET : DXL_MORE));
  }
  CHECK(same_packet(r, &again));
}

int LLVMFuzzerTestOneInput(const uint8_t* data, size_t n) {
  if (n == 0) return 0;
  uint32_t draw = data[0] * 2654435761u + 1;   // the chunk sizes, from the first byte
  data++;
  n--;
  dxl_reader bytewise, chunked;
  dxl_reader_reset(&bytewise);
  dxl_reader_reset(&chunked);
  size_t at = 0;
  while (at < n) {
    draw = draw * 1103515245u + 12345u;
    size_t chunk = 1 + (draw >> 16) % 300;
    if (chunk > n - at) chunk = n - at;
    size_t used = 0;
    int result = dxl_reader_feed_bytes(&chunked, data + at, chunk, &used);
    check_reader(&chunked, result);
    CHECK(used >= 1 && used <= chunk);
    CHECK(result == DXL_MORE ? used == chunk : 1);
    for (size_t i = 0; i < used; i++) {
      int one = dxl_reader_feed(&bytewise, data[at + i]);
      check_reader(&bytewise, one);
      CHECK(one == (i + 1 == used ? result : DXL_MORE));
    }
    if (result == DXL_PACKET) {
      CHECK(same_packet(&bytewise, &chunked));
      round_trip(&chunked);
    }
    at += used;
  }
  return 0;
}
