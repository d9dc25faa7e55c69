// sd_config.h (public): scalar type, compile-time limits and math wrappers of the servodyn core.
//
// The core is built twice from one source: with sd_real = double for the host and the
// simulation (the default), and with sd_real = float for the microcontroller (-DSD_SINGLE).
#ifndef SD_CONFIG_H
#define SD_CONFIG_H

#include <math.h>

#ifdef SD_SINGLE
typedef float sd_real;
#define SD_R(x)       ((float)(x))
#define sd_sin(x)     sinf(x)
#define sd_cos(x)     cosf(x)
#define sd_sqrt(x)    sqrtf(x)
#define sd_fabs(x)    fabsf(x)
#define sd_tanh(x)    tanhf(x)
#define sd_exp(x)     expf(x)
#define SD_EPS        1.1920929e-07f
#else
typedef double sd_real;
#define SD_R(x)       ((double)(x))
#define sd_sin(x)     sin(x)
#define sd_cos(x)     cos(x)
#define sd_sqrt(x)    sqrt(x)
#define sd_fabs(x)    fabs(x)
#define sd_tanh(x)    tanh(x)
#define sd_exp(x)     exp(x)
#define SD_EPS        2.220446049250313e-16
#endif

// a finite-number test that survives -ffast-math and needs no libm: x - x is 0 only for finite x
#define SD_ISFINITE(x) ((x) - (x) == (x) - (x))

// Largest model the build accepts; an MCU build sets smaller limits with -D.
#ifndef SD_MAX_BODY
#define SD_MAX_BODY 128
#endif
#ifndef SD_MAX_DOF
#define SD_MAX_DOF 128
#endif
#define SD_MAX_JOINT_DOF 3
// a quaternion (free root, ball joint) takes one coordinate more than its 3 rotational dofs
#define SD_MAX_Q (SD_MAX_DOF + SD_MAX_DOF / 3 + 1)

#endif  // SD_CONFIG_H
