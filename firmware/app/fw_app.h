// fw_app.h: the firmware's control application: types of the generated constant data
// (servodyn_gen.c, written by `servodyn codegen`) and the fault codes the host reads.
#ifndef FW_APP_H
#define FW_APP_H

#include <stdint.h>

#include "servodyn.h"
#include "servodyn_gen.h"

// One joint's servo: register units <-> joint SI units (hal/dynamixel/units.py's conventions):
//   horn angle = direction * gear_ratio * q + zero_offset,  position ticks = horn / rad_per_tick
//   joint torque = nm_per_amp * motor current,  Goal Current = direction * current / amp_per_unit
typedef struct fw_servo_ {
  uint8_t id;
  uint16_t model_number;
  sd_real direction;          // +1 / -1
  sd_real zero_offset;        // rad, horn angle at q = 0
  sd_real gear_ratio;         // horn turns per joint turn
  sd_real rad_per_tick;       // horn rad per Present Position unit
  sd_real radps_per_unit;     // horn rad/s per Present Velocity unit
  sd_real amp_per_unit;       // A per current unit
  sd_real nm_per_amp;         // joint N m per motor A (torque constant x gear ratio)
  sd_real current_limit;      // A: commands are clamped here (limiting, not a fault)
  sd_real q_min, q_max;       // rad: joint range; outside it by FW_RANGE_MARGIN is a fault
  sd_real qd_max;             // rad/s
  sd_real friction_coulomb;   // N m at the joint, compensated on the desired velocity (smoothed)
  sd_real friction_viscous;   // N m s/rad at the joint
  sd_real following_error;    // rad: |q_d - q| above it is a fault ([safety] following_error_rad)
  // the momentum observer (sd_observer.h) and its contact rule, servodyn.loop.contact's values
  sd_real observer_gain;      // 1/s: K_O, the residual's bandwidth
  sd_real observer_lowpass;   // rad/s: the low-pass on the residual
  sd_real contact_threshold;  // N m: |residual| above it, contact_debounce ticks in a row, is a contact
} fw_servo;

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

// Fault codes: the firmware's exit status under QEMU and the code in its report line.
enum fw_fault_ {
  FW_OK = 0,
  FW_FAULT_TIMEOUT = 10,      // a servo did not answer (its id is reported)
  FW_FAULT_STATUS = 11,       // a servo's status carried an error (alert: hardware error)
  FW_FAULT_CORRUPT = 12,      // a reply that failed its CRC or had the wrong shape
  FW_FAULT_NONFINITE = 13,    // a NaN or infinite number in the control step
  FW_FAULT_OVERRUN = 14,      // a tick's work took longer than its period
  FW_FAULT_RANGE = 15,        // a joint measured outside its range (sensor or mechanics)
  FW_FAULT_SETUP = 16,        // a servo refused the set-up (wrong model, a write error)
  FW_FAULT_OVERFLOW = 17,     // finite measurements, a non-finite torque (overflow in the step)
  FW_FAULT_CONTACT = 18,      // the momentum observer's residual crossed a joint's contact threshold
  FW_FAULT_FOLLOWING_ERROR = 19,  // |q_d - q| of a joint above its following-error limit
  FW_FAULT_STALL = 20,        // a joint at its torque limit without moving, longer than the stall time
};

const char* fw_fault_name(int code);

// Each tick's figures, after its write: the native loop's board logs them (weak: none by default).
void fw_record_tick(long tick, const sd_real* q_d, const sd_real* q, const sd_real* qd, const sd_real* tau,
                    const sd_real* current);

#endif  // FW_APP_H
