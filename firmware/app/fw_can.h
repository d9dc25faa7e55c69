// fw_can.h: the CAN bus of the general application (fw_link.c): MIT-style motors beside (or
// instead of) the Dynamixel bus, framed by the MIT codec (hal/can/c/canmotor.c) and carried by the
// board's CAN controller (board_can_*, below). hal/can/backend.py is the host's same bus: the same
// frames in the same order, so the same motors answer the same way.
//
// A tick: fw_can_read takes the answers to the last tick's command frames (each motor answers one
// with its state; with none owed, an "enter motor mode" frame asks again), then fw_can_write sends
// every motor its command frame and returns without waiting: the answers come while the loop sleeps.
// So the state a tick reads is the motors' answer to the previous tick's command, as the host's.
// Joint <-> motor: p = direction gear q + zero_offset, v = direction gear qd, t = tau / (direction gear).
// The command is torque alone (p = zero_offset, v = kp = kd = 0): the controller closes the loop.
#ifndef FW_CAN_H
#define FW_CAN_H

#include <stdint.h>

#include "canmotor.h"
#include "fw_app.h"

// the dialects (link.h's link_dialect_, hal/can/dialects.py)
enum fw_can_dialect_ { FW_CAN_MIT = 1, FW_CAN_DAMIAO = 2, FW_CAN_CUBEMARS = 3 };

#define FW_CAN_TORQUE_BITS 12u          // the command's torque field: its code is the joint's goal

typedef struct fw_can_motor_ {
  int joint;                            // the joint it drives (model dof order)
  uint16_t id, reply_id;                // command id; the id its answers come on
  uint8_t dialect;                      // an fw_can_dialect_
  cm_ranges ranges;
} fw_can_motor;

typedef struct fw_can_ {
  const fw_servo* servo;                // the robot's joints
  int n;                                // motors
  fw_can_motor motor[SD_MAX_DOF];
  uint8_t pending[SD_MAX_DOF];          // 1: motor k owes an answer
  int torque_on;
  int fault_joint;                      // the joint a fault names, -1 none
  cm_reply state[SD_MAX_DOF];           // each motor's last answer
  int16_t effort[SD_MAX_DOF];           // by joint: the last answer's torque field code (servo units)
  uint32_t foreign;                     // frames on no motor's reply id, skipped
} fw_can;

void fw_can_init(fw_can* c, const fw_servo* servo);
// Motor of joint `joint`: its ids, dialect and MIT ranges (p_max, v_max, t_max, kp_max, kd_max).
void fw_can_add(fw_can* c, int joint, uint16_t id, uint16_t reply_id, uint8_t dialect, const sd_real* range);
// Each Damiao motor checked as the host's backend checks it (MIT mode, its PMAX / VMAX / TMAX the
// configuration's; FW_FAULT_SETUP if not) and its CAN timeout written (0.1 s: a controller that
// stops leaves it limp); then "exit motor mode" to every motor (each must answer), then "enter
// motor mode": torque on.
int fw_can_setup(fw_can* c);
// Every motor's state in joint units (q, qd; current: joint torque / nm_per_amp) into the arrays
// of joints, by joint index: 0, or a fault code with fault_joint set.
int fw_can_read(fw_can* c, sd_real* q, sd_real* qd, sd_real* current);
// Every motor's command frame, the torque of its joint (tau by joint index); goal[joint] gets the
// torque field's code; *limited |= 1 when a torque was clamped into the motor's range. 0, or a
// fault code with fault_joint set (a frame the controller would not take).
int fw_can_write(fw_can* c, const sd_real* tau, int16_t* goal, int* limited);
// "exit motor mode" to every motor, their answers taken when they come in time.
void fw_can_torque_off(fw_can* c);

//---------------------------------- the board's CAN controller ----------------------------------
// Classic frames, 11-bit ids. A board without one keeps fw_can.c's weak defaults: no CAN bus.
// Linux: an SLCAN adapter on a tty (can=PATH, firmware/posix/board_slcan.c); STM32F405: bxCAN1
// (firmware/boards/stm32f405/board_can.c).

// Open the bus at `bitrate`: 1 when the board has a CAN bus and it is open, else 0.
int board_can_open(uint32_t bitrate);
// Queue a frame: 1, or 0 when it could not be sent.
int board_can_send(uint16_t id, const uint8_t* data, uint8_t len);
// Take the oldest received frame: 1, or 0 when none has arrived.
int board_can_take(uint16_t* id, uint8_t* data, uint8_t* len);
// Wait until a frame is there to take: 1, or 0 when the motors are taken for silent (the board's
// reply timeout). The caller holds the clock (board_clock_hold) around it, as for the UART.
int board_can_wait(void);

#endif  // FW_CAN_H
