// fuzz.h: what the Dynamixel codec's libFuzzer targets share beyond fuzz/check.h (CHECK, the
// input read a byte at a time): a packet's fields for comparison, the reader's invariants.
#ifndef FUZZ_H
#define FUZZ_H

#include "../check.h"
#include "dxl.h"

// the packet a reader holds after DXL_PACKET: equal fields, equal params
static inline int same_packet(const dxl_reader* a, const dxl_reader* b) {
  return a->id == b->id && a->instruction == b->instruction && a->error == b->error &&
         a->nparam == b->nparam && memcmp(a->param, b->param, a->nparam) == 0;
}

// the reader's invariants after any byte
static inline void check_reader(const dxl_reader* r, int result) {
  CHECK(result >= DXL_BAD_FRAME && result <= DXL_PACKET);
  CHECK(r->nparam <= DXL_MAX_PARAM);
  if (result == DXL_PACKET) CHECK(r->id <= DXL_MAX_ID || r->id == DXL_BROADCAST);
}

#endif  // FUZZ_H
