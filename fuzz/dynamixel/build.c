// build.c: libFuzzer target for the Dynamixel packet builders and the byte stuffing
// (hal/dynamixel/c/dxl.c). The input chooses a builder, its arguments and the output buffer's
// capacity (allocated at exactly that size, so AddressSanitizer sees any write past it). A frame
// that was built is read back, byte after byte, to the id, instruction and params it was built
// from; a builder that returns 0 had a bad id or too small a buffer.
#include "fuzz.h"

static uint16_t take16(input* in) {
  uint16_t low = take(in);
  return (uint16_t)(low | take(in) << 8);
}

enum { MAX_COUNT = 40, MAX_PARAMS = 600 };

int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  input in = {data, size};
  uint8_t which = take(&in) % 7;
  size_t cap = take16(&in) % 1400;
  uint8_t id = take(&in);
  uint8_t instruction = take(&in);
  uint16_t address = take16(&in);
  uint16_t width = take(&in) % 9;   // register bytes per servo
  size_t count = take(&in) % MAX_COUNT;
  uint8_t ids[MAX_COUNT];
  uint16_t addresses[MAX_COUNT], sizes[MAX_COUNT];
  for (size_t k = 0; k < count; k++) {
    ids[k] = take(&in);
    addresses[k] = take16(&in);
    sizes[k] = take16(&in);
  }
  uint8_t mode = take(&in);   // sync or bulk read: plain or fast
  // the rest is the payload (params, or the registers of a sync write)
  size_t npayload = in.n < MAX_PARAMS ? in.n : MAX_PARAMS;
  const uint8_t* payload = in.p;
  uint8_t registers[MAX_COUNT * 8] = {0};
  memcpy(registers, payload, npayload < sizeof registers ? npayload : sizeof registers);

  // built twice: into a buffer of the drawn capacity, and into one that always fits
  static uint8_t roomy[4096];
  uint8_t* out = malloc(cap ? cap : 1);
  size_t len = 0, full = 0, nexpect = 0;   // the frames, and how many params they read back to
  uint8_t expect_id = DXL_BROADCAST;
  const uint8_t* expect = NULL;  // params to compare, when the target restates them
  for (int pass = 0; pass < 2; pass++) {
    uint8_t* o = pass ? roomy : out;
    size_t c = pass ? sizeof roomy : cap;
    size_t* got = pass ? &full : &len;
    switch (which) {
      case 0:
        *got = dxl_packet(o, c, id, instruction, payload, npayload);
        expect_id = id, nexpect = npayload, expect = payload;
        if (instruction == DXL_STATUS && npayload) nexpect--, expect++;   // ERR is not a param
        break;
      case 1:
        *got = dxl_ping(o, c, id);
        expect_id = id, instruction = DXL_PING;
        break;
      case 2:
        *got = dxl_read(o, c, id, address, width);
        expect_id = id, instruction = DXL_READ, nexpect = 4;
        break;
      case 3:
        *got = dxl_write(o, c, id, address, payload, (uint16_t)npayload);
        expect_id = id, instruction = DXL_WRITE, nexpect = 2 + npayload;
        break;
      case 4:
        *got = dxl_sync_write(o, c, address, width, ids, count, registers);
        instruction = DXL_SYNC_WRITE, nexpect = 4 + count * (1 + width);
        break;
      case 5:
        instruction = mode & 1 ? DXL_FAST_SYNC_READ : DXL_SYNC_READ;
        *got = (mode & 1 ? dxl_fast_sync_read : dxl_sync_read)(o, c, address, width, ids, count);
        nexpect = 4 + count;
        break;
      default:
        instruction = mode & 1 ? DXL_FAST_BULK_READ : DXL_BULK_READ;
        *got = (mode & 1 ? dxl_fast_bulk_read : dxl_bulk_read)(o, c, ids, addresses, sizes, count);
        nexpect = 5 * count;
        break;
    }
  }
  int id_ok = expect_id <= DXL_MAX_ID || expect_id == DXL_BROADCAST;
  // a bad id refuses, and a frame fits exactly when the capacity holds it, byte for byte the same
  CHECK(id_ok ? full > 0 : full == 0);
  CHECK(len == (cap >= full ? full : 0));
  CHECK(memcmp(out, roomy, len) == 0);
  if (len == 0) {
    free(out);
    return 0;
  }
  CHECK(id_ok);
  dxl_reader r;
  dxl_reader_reset(&r);
  int result = DXL_MORE;
  size_t i = 0;
  for (; i < len && result == DXL_MORE; i++) {
    result = dxl_reader_feed(&r, out[i]);
    check_reader(&r, result);
  }
  int status_without_err = instruction == DXL_STATUS && which == 0 && npayload == 0;
  if (nexpect > DXL_MAX_PARAM) {
    CHECK(result == DXL_TOO_LONG);
  } else if (status_without_err) {
    CHECK(result == DXL_BAD_FRAME && i == len);
  } else {
    CHECK(result == DXL_PACKET && i == len);
    CHECK(r.id == expect_id && r.instruction == instruction && r.nparam == nexpect);
    if (expect) CHECK(memcmp(r.param, expect, nexpect) == 0);
    if (which == 0 && instruction == DXL_STATUS) CHECK(r.error == payload[0]);
  }
  free(out);
  return 0;
}
