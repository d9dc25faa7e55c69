// fw_plan.h: the compiled-in robot of fw_main.c: the types of the constant data `servodyn codegen`
// writes (servodyn_gen.c): its model, servos, gain schedules, swing and timing.
#ifndef FW_PLAN_H
#define FW_PLAN_H

#include "fw_app.h"
#include "servodyn_gen.h"

// A gain schedule: knots at times t (s from the start of its phase), linear in between.
typedef struct fw_gains_ {
  int n;
  sd_real t[FW_NGAIN_SWING > FW_NGAIN_HOME ? FW_NGAIN_SWING : FW_NGAIN_HOME];
  sd_real kp[FW_NGAIN_SWING > FW_NGAIN_HOME ? FW_NGAIN_SWING : FW_NGAIN_HOME][FW_NJOINT];
  sd_real kd[FW_NGAIN_SWING > FW_NGAIN_HOME ? FW_NGAIN_SWING : FW_NGAIN_HOME][FW_NJOINT];
  sd_real error_lowpass[FW_NJOINT];   // the low-pass of the errors the gains act on (sd_control.h)
} fw_gains;

typedef struct fw_plan_ {
  sd_real small_time_step;    // s: the control period, one SysTick
  int update_ticks;           // control periods per inverse dynamics (time_step)
  long home_ticks;            // periods of the minimum-jerk move to the swing's start
  long swing_ticks;           // periods of the swing
  uint32_t baud;              // the configured bus rate (QEMU's UART does not model it)
  uint8_t watchdog_units;     // Bus Watchdog (98), 20 ms units
  uint16_t read_address, read_size;   // the fast sync read: Present Current .. Position
  uint16_t goal_address;      // Goal Current
  sd_real overrun_tolerance;  // s the plan may fall behind the clock on a host OS (native loop)
  sd_real friction_speed;     // rad/s: the compensated Coulomb friction's smoothing
  long stall_ticks;           // periods at the torque limit without moving that are a stall
  sd_real stall_speed;        // rad/s: slower than this a joint "does not move"
  sd_real stall_share;        // of the joint's torque limit: "at its limit"
  int contact;                // 1: the observer watches for contact ([safety] contact)
  int contact_debounce;       // ticks in a row over a threshold that are a contact
  long contact_arm_ticks;     // ticks after the observer's start (homing's first) before one counts
} fw_plan;

extern const sd_model fw_model;
extern const sd_trajectory fw_swing;
extern const fw_servo fw_servos[FW_NJOINT];
extern const fw_gains fw_home_gains, fw_swing_gains;
extern const fw_plan fw_plan_;

extern const sd_model fw_model;
extern const sd_trajectory fw_swing;
extern const fw_servo fw_servos[FW_NJOINT];
extern const fw_gains fw_home_gains, fw_swing_gains;
extern const fw_plan fw_plan_;

#endif  // FW_PLAN_H
