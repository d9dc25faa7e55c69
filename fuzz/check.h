// check.h: what every libFuzzer target here shares: a check that aborts with the failed condition
// (libFuzzer saves the input as a crash), and the input read as arguments, a byte at a time.
#ifndef FUZZ_CHECK_H
#define FUZZ_CHECK_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define CHECK(cond)                                                                   \
  do {                                                                                \
    if (!(cond)) {                                                                    \
      fprintf(stderr, "%s:%d: check failed: %s\n", __FILE__, __LINE__, #cond);       \
      abort();                                                                        \
    }                                                                                 \
  } while (0)

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

#endif  // FUZZ_CHECK_H
