// fw_app.h: the firmware's control application, whatever gives it its robot: a servo's units and
// limits, the guards, the fault codes the host reads, and the controller step (fw_step.c) that both
// applications run: fw_main.c (a robot and motion compiled in by `servodyn codegen`, fw_plan.h) and
// fw_link.c (a robot and motion loaded over the host link, firmware/link).
#ifndef FW_APP_H
#define FW_APP_H

#include <stdint.h>

#include "dxl.h"
#include "servodyn.h"

// One joint's servo: register units <-> joint SI units (hal/dynamixel/units.py's conventions):
//   horn angle = direction * gear_ratio * q + zero_offset,  position ticks = horn / rad_per_tick
//   joint torque = nm_per_amp * motor current,  Goal Current = direction * current / amp_per_unit
typedef struct fw_servo_ {
  uint8_t id;
  uint8_t can;                // 1: a CAN motor (fw_can.h converts its torque; the unit scales unused)
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

// The guards' constants beyond each servo's own (host/loop/safety.py's table, contact's rule).
typedef struct fw_guards_ {
  long stall_ticks;           // periods at the torque limit without moving that are a stall
  sd_real stall_speed;        // rad/s: slower than this a joint "does not move"
  sd_real stall_share;        // of the joint's torque limit: "at its limit"
  int contact;                // 1: the observer watches for contact ([safety] contact)
  int contact_debounce;       // ticks in a row over a threshold that are a contact
  long contact_arm_ticks;     // ticks after the observer's start before one counts
} fw_guards;

// The controller step of one tick on the measured q, qd and current (fw_step.c): the momentum
// observer, the core's controller (feed-forward, PD, friction; sd_control_step), then the guards
// (range, following error, stall, contact) and joint torque -> servo command, clamped.
typedef struct fw_step_ {
  const sd_model* model;
  const fw_servo* servo;      // njoint servos, model dof order
  const fw_guards* guards;
  int njoint;
  sd_data data;
  sd_control_config control;
  sd_control_state cstate;
  sd_observer_config oconfig;
  sd_observer_state observer;
  sd_real tau_measured[SD_MAX_DOF];  // N m at the joint: nm_per_amp x the measured current
  int over[SD_MAX_DOF];              // ticks in a row each joint's |residual| is over its threshold
  long pressed[SD_MAX_DOF];          // ticks each joint has been at its torque limit without moving
  sd_real tau[SD_MAX_DOF];           // the step's joint torque
  int16_t goal[SD_MAX_DOF];          // the step's command, servo units
  int fault_servo;                   // the servo a fault names (its id), -1 none
  int fault_joint;                   // and its joint (model dof order), -1 none
  int contact_servo;                 // a contact's: the last joint over its threshold (its servo id)
  sd_real fault_value;               // a guard's: the following error (rad), the stalled torque or
                                     // the contact's |residual| (N m)
} fw_step;

// Set up the step for a robot: the controller's friction and the observer's constants from the
// servos, the observer's period dt (the caller sets control.mode, update_ticks and the gains, and
// checks the observer's constants with sd_observer_check).
void fw_step_init(fw_step* s, const sd_model* model, const fw_servo* servo, int njoint, const fw_guards* guards,
                  sd_real dt, sd_real friction_speed);
// A desired position outside a joint's range is clamped to it, at rest (limiting): 1 when one was.
int fw_step_clamp_plan(const fw_step* s, sd_real* q_d, sd_real* qd_d, sd_real* qdd_d);
// Start the observer at the measured state (r = 0), the guards' counts at zero.
void fw_step_start(fw_step* s, const sd_real* q, const sd_real* qd);
// The observer's sample of this tick.
void fw_step_observe(fw_step* s, const sd_real* q, const sd_real* qd, const sd_real* current);
// The controller's torque into s->tau: 0, or FW_FAULT_NONFINITE / FW_FAULT_OVERFLOW.
int fw_step_control(fw_step* s, const sd_real* q_d, const sd_real* qd_d, const sd_real* qdd_d, const sd_real* q,
                    const sd_real* qd);
// The guards on the tick's state and torque, then torque -> s->goal for the Dynamixel servos (a
// CAN motor's goal is its bus's, fw_can_write): 0 or a fault code (s->fault_servo, fault_joint,
// fault_value set); *limited |= 1 when a command was clamped.
int fw_step_finish(fw_step* s, const sd_real* q_d, const sd_real* q, const sd_real* qd, int* limited);

// The Dynamixel bus (fw_bus.c): every function but the writes waits for its replies; 0 or a fault
// code with fault_servo set (the servo's id, -1 none).
#define FW_TX_MAX (10 + 5 * SD_MAX_DOF + 16)   // bytes of the largest instruction packet
typedef struct fw_bus_ {
  const fw_servo* servo;
  int n;
  uint8_t ids[SD_MAX_DOF];
  int fault_servo;
  int16_t current_units[SD_MAX_DOF];   // the last read's Present Current, servo units
  dxl_reader reader;
  size_t rx_got;                       // bytes of the last reply taken
  uint8_t tx[FW_TX_MAX];
  uint8_t read_packet[FW_TX_MAX];      // the fast sync read, built once
  size_t read_len;
} fw_bus;

void fw_bus_init(fw_bus* b, const fw_servo* servo, int n);
// Check each servo's model number, set it up (Return Delay 0, current mode, Bus Watchdog), Goal
// Current 0 and torque on.
int fw_bus_setup(fw_bus* b);
// Every servo's state in joint units.
int fw_bus_read(fw_bus* b, sd_real* q, sd_real* qd, sd_real* current);
void fw_bus_write_goals(fw_bus* b, const int16_t* goal);
void fw_bus_torque_off(fw_bus* b);

// Each tick's figures, after its write: the native loop's board logs them (weak: none by default).
void fw_record_tick(long tick, int njoint, const sd_real* q_d, const sd_real* q, const sd_real* qd,
                    const sd_real* tau, const sd_real* current);

#endif  // FW_APP_H
