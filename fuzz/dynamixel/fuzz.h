// fuzz.h: what the Dynamixel codec's libFuzzer targets share: a check that aborts with the
// failed condition (libFuzzer saves the input as a crash), and a packet's fields for comparison.
#ifndef FUZZ_H
#define FUZZ_H

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "dxl.h"

#define CHECK(cond)                                                                   \
  do {                                                                                \
    if (!(cond)) {                                                                    \
      fprintf(stderr, "%s:%d: check failed: %s\n", __FILE__, __LINE__, #cond);       \
      abort();                                                                        \
    }                                                                                 \
  } while (0)

// the packet a reader holds after DXL_PACKET: equal fields, equal params
static inline int same_packet(const dxl_reader* a, const dxl_reader* b) {
  return a->id == b->id && a->instruction == b->instruction && a->error == b->error &&
         a->nparam == b->nparam && memcmp(a->param, b->param, a->nparam) == 0;
}

// the input read as arguments, a byte at a time (zeros once it runs out)
typedef struct input_ {
  const uint8_t* p;
  size_t n;
} input;

static inline uint8_t take(input* in) {
  if (in->n == 0) return 0;
  in->n--;
  return *in->p++;
}

// the reader's invariants after any byte
static inline void check_reader(const dxl_reader* r, int result) {
  CHECK(result >= DXL_BAD_FRAME && result <= DXL_PACKET);
  CHECK(r->nparam <= DXL_MAX_PARAM);
  if (result == DXL_PACKET) CHECK(r->id <= DXL_MAX_ID || r->id == DXL_BROADCAST);
}

#endif  // FUZZ_H
