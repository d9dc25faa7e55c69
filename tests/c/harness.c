// harness.c: the check functions and the runner of the C core tests.
//
// usage: test_core [-v]    -v lists every test with its number of checks
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "harness.h"
#include "sd_config.h"

static int g_passed, g_failed;
static char g_context[256];

void sdt_context(const char* fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  vsnprintf(g_context, sizeof g_context, fmt, ap);
  va_end(ap);
}

// record one check; on failure print where, what, the numbers and why
static int record(int ok, const char* file, int line, const char* expr, const char* numbers,
                  const char* reason) {
  if (ok) {
    g_passed++;
    return 1;
  }
  g_failed++;
  printf("FAIL %s:%d: %s%s%s\n     %s\n     reason: %s\n", file, line, expr,
         g_context[0] ? " -- " : "", g_context, numbers, reason);
  return 0;
}

int sdt_expect_near(const char* file, int line, const char* expr, double measured,
                    double expected, double tol, const char* reason) {
  double err = measured - expected;
  if (err < 0) err = -err;
  char numbers[160];
  snprintf(numbers, sizeof numbers, "measured %.17g, expected %.17g, |error| %.3g > tolerance %.3g",
           measured, expected, err, tol);
  return record(err <= tol, file, line, expr, numbers, reason);
}

int sdt_expect_le(const char* file, int line, const char* expr, double measured, double limit,
                  const char* reason) {
  char numbers[160];
  snprintf(numbers, sizeof numbers, "measured %.6g > tolerance %.6g", measured, limit);
  return record(measured <= limit, file, line, expr, numbers, reason);
}

int sdt_expect_ge(const char* file, int line, const char* expr, double measured, double limit,
                  const char* reason) {
  char numbers[160];
  snprintf(numbers, sizeof numbers, "measured %.6g < limit %.6g", measured, limit);
  return record(measured >= limit, file, line, expr, numbers, reason);
}

int sdt_expect_int(const char* file, int line, const char* expr, long measured, long expected,
                   const char* reason) {
  char numbers[160];
  snprintf(numbers, sizeof numbers, "measured %ld, expected %ld", measured, expected);
  return record(measured == expected, file, line, expr, numbers, reason);
}

static const struct {
  const char* file;
  const sdt_test* tests;
} g_suites[] = {
  {"test_model.c", sdt_model_tests},
  {"test_rnea.c", sdt_rnea_tests},
  {"test_regressor.c", sdt_regressor_tests},
  {"test_observer.c", sdt_observer_tests},
  {"test_ag.c", sdt_ag_tests},
  {"test_integrate.c", sdt_integrate_tests},
  {"test_trajectory.c", sdt_trajectory_tests},
  {"test_control.c", sdt_control_tests},
  {"test_dxl.c", sdt_dxl_tests},
  {"test_link.c", sdt_link_tests},
  {"test_fw_can.c", sdt_fw_can_tests},
};

int main(int argc, char** argv) {
  int verbose = argc > 1 && strcmp(argv[1], "-v") == 0;
#ifdef SD_SINGLE
  printf("servodyn C core tests, sd_real = float\n");
#else
  printf("servodyn C core tests, sd_real = double\n");
#endif
  for (size_t s = 0; s < sizeof g_suites / sizeof g_suites[0]; s++) {
    int suite_passed = g_passed, suite_failed = g_failed, ntest = 0;
    for (const sdt_test* t = g_suites[s].tests; t->fn; t++, ntest++) {
      int passed = g_passed, failed = g_failed;
      g_context[0] = 0;
      t->fn();
      if (verbose || g_failed > failed) {
        printf("  %-4s %s: %d checks, %d failed\n", g_failed > failed ? "FAIL" : "ok", t->name,
               g_passed - passed + g_failed - failed, g_failed - failed);
      }
    }
    printf("  %-18s %3d tests, %4d checks passed, %d failed\n", g_suites[s].file, ntest,
           g_passed - suite_passed, g_failed - suite_failed);
  }
  printf("%d passed, %d failed\n", g_passed, g_failed);
  return g_failed ? 1 : 0;
}
