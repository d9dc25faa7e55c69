// harness.h: a tiny self-contained test harness for the servodyn C core.
//
// A test is a void function listed in its file's table; it makes checks with the EXPECT_*
// macros. Every check compares one measured number with a tolerance and carries the reason it
// must hold; a failing check prints the number, the tolerance, the reason and the context set
// by sdt_context(). The runner (harness.c) ends with "N passed, M failed" and exits non-zero
// on any failure.
#ifndef SDT_HARNESS_H
#define SDT_HARNESS_H

typedef struct sdt_test_ {
  const char* name;
  void (*fn)(void);
} sdt_test;

// the test tables, one per core source file, each ended by {0, 0}
extern const sdt_test sdt_model_tests[];
extern const sdt_test sdt_rnea_tests[];
extern const sdt_test sdt_regressor_tests[];
extern const sdt_test sdt_observer_tests[];
extern const sdt_test sdt_ag_tests[];
extern const sdt_test sdt_integrate_tests[];
extern const sdt_test sdt_trajectory_tests[];
extern const sdt_test sdt_control_tests[];
extern const sdt_test sdt_dxl_tests[];      // the firmware's Dynamixel codec (hal/dynamixel/c)
extern const sdt_test sdt_link_tests[];     // the host link (firmware/link)
extern const sdt_test sdt_fw_can_tests[];   // the application's CAN bus (firmware/app/fw_can.c)

// Describe the case under test (printf-style); failures print it. Cleared before each test.
void sdt_context(const char* fmt, ...) __attribute__((format(printf, 1, 2)));

int sdt_expect_near(const char* file, int line, const char* expr, double measured,
                    double expected, double tol, const char* reason);
int sdt_expect_le(const char* file, int line, const char* expr, double measured, double limit,
                  const char* reason);
int sdt_expect_ge(const char* file, int line, const char* expr, double measured, double limit,
                  const char* reason);
int sdt_expect_int(const char* file, int line, const char* expr, long measured, long expected,
                   const char* reason);

// |measured - expected| <= tol (fails on NaN)
#define EXPECT_NEAR(measured, expected, tol, reason)                                        \
  sdt_expect_near(__FILE__, __LINE__, #measured, (double)(measured), (double)(expected),    \
                  (double)(tol), (reason))
// measured <= limit (fails on NaN); for error norms computed by the test
#define EXPECT_LE(measured, limit, reason) \
  sdt_expect_le(__FILE__, __LINE__, #measured, (double)(measured), (double)(limit), (reason))
// measured >= limit (fails on NaN)
#define EXPECT_GE(measured, limit, reason) \
  sdt_expect_ge(__FILE__, __LINE__, #measured, (double)(measured), (double)(limit), (reason))
// integer equality: error codes, counters
#define EXPECT_INT(measured, expected, reason) \
  sdt_expect_int(__FILE__, __LINE__, #measured, (long)(measured), (long)(expected), (reason))

#endif  // SDT_HARNESS_H
