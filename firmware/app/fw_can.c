// fw_can.c: the CAN bus of the general application (fw_can.h): MIT-style motors, their frames
// packed and unpacked by the MIT codec (hal/can/c/canmotor.c), on the board's CAN controller.
// Each answer is routed as hal/can/backend.py routes it: the id it came on, its length and the motor
// id it names (hal/can/dialects.py: mit and CubeMars byte 0, Damiao byte 0's low nibble).
#include "fw_can.h"

#include <string.h>

#include "board.h"

// a board without a CAN controller (the MPS2 images): no CAN bus
__attribute__((weak)) int board_can_open(uint32_t bitrate) {
  (void)bitrate;
  return 0;
}
__attribute__((weak)) int board_can_send(uint16_t id, const uint8_t* data, uint8_t len) {
  (void)id, (void)data, (void)len;
  return 0;
}
__attribute__((weak)) int board_can_take(uint16_t* id, uint8_t* data, uint8_t* len) {
  (void)id, (void)data, (void)len;
  return 0;
}
__attribute__((weak)) int board_can_wait(void) { return 0; }

#define DAMIAO_DISABLED 0x0
#define DAMIAO_ENABLED 0x1
// Damiao's registers (hal/can/dialects.py's REG_*, the vendor's numbers) and the CAN timeout the
// host's backend gives a motor (hal/can/backend.py's MOTOR_CAN_TIMEOUT, in 50 us units)
#define DAMIAO_REG_TIMEOUT 9
#define DAMIAO_REG_CTRL_MODE 10
#define DAMIAO_REG_PMAX 21                 // then VMAX 22, TMAX 23: float32
#define DAMIAO_MIT_MODE 1
#define DAMIAO_TIMEOUT_UNITS 2000u         // 0.1 s: a controller that stops leaves the motor limp

void fw_can_init(fw_can* c, const fw_servo* servo) {
  c->servo = servo;
  c->n = 0;
  c->torque_on = 0;
  c->fault_joint = -1;
  c->foreign = 0;
  for (int k = 0; k < SD_MAX_DOF; k++) c->pending[k] = 0, c->effort[k] = 0;
}

void fw_can_add(fw_can* c, int joint, uint16_t id, uint16_t reply_id, uint8_t dialect, const sd_real* range) {
  fw_can_motor* m = &c->motor[c->n++];
  m->joint = joint;
  m->id = id;
  m->reply_id = reply_id;
  m->dialect = dialect;
  m->ranges = (cm_ranges){.p_max = range[0], .v_max = range[1], .t_max = range[2], .kp_max = range[3],
                          .kd_max = range[4]};
}

//---------------------------------- answers ----------------------------------------------------

// the motor an answer is from: its reply id, a length of its dialect's, the motor id it names; -1 none
static int route(const fw_can* c, uint16_t id, const uint8_t* d, uint8_t len) {
  for (int k = 0; k < c->n; k++) {
    const fw_can_motor* m = &c->motor[k];
    if (m->reply_id != id) continue;
    if (m->dialect == FW_CAN_DAMIAO ? len == 8 && (d[0] & 0xFu) == (m->id & 0xFu)
                                    : (m->dialect == FW_CAN_MIT ? len == 6 || len == 7 : len == 8) && d[0] == m->id)
      return k;
  }
  return -1;
}

static int unpack(const fw_can_motor* m, const uint8_t* d, uint8_t len, cm_reply* y) {
  switch (m->dialect) {
    case FW_CAN_MIT: return cm_unpack_mit_reply(&m->ranges, d, len, y);
    case FW_CAN_DAMIAO: return cm_unpack_damiao_feedback(&m->ranges, d, len, y);
    default: return cm_unpack_cubemars_reply(&m->ranges, d, len, y);
  }
}

// a status that is a fault (hal/can/dialects.py's): Damiao disabled while torque is on, or any
// status but enabled / disabled; a CubeMars error code; the mit firmware reports none
static int faulted(const fw_can* c, const fw_can_motor* m, const cm_reply* y) {
  if (m->dialect == FW_CAN_DAMIAO)
    return !(y->status == DAMIAO_ENABLED || (y->status == DAMIAO_DISABLED && !c->torque_on));
  return m->dialect == FW_CAN_CUBEMARS && y->status != 0;
}

static int fault_at(fw_can* c, int k, int code) {
  c->fault_joint = k < 0 ? -1 : c->motor[k].joint;
  for (int i = 0; i < c->n; i++) c->pending[i] = 0;
  return code;
}

// One frame taken (1); or none there, and the bus waited on with the control clock held (0: try
// again; -1: nothing came within the board's reply time, a time-out)
static int take_or_wait(uint16_t* id, uint8_t* d, uint8_t* len) {
  if (board_can_take(id, d, len)) return 1;
  board_clock_hold();
  int came = board_can_wait();
  board_clock_release();
  return came ? 0 : -1;
}

static int first_pending(const fw_can* c) {
  for (int k = 0; k < c->n; k++)
    if (c->pending[k]) return k;
  return -1;
}

// Every owed answer, decoded into c->state; the wait for them holds the clock (board.h). 0, or
// FW_FAULT_TIMEOUT (the first motor still silent), FW_FAULT_STATUS (check: a fault status),
// FW_FAULT_CORRUPT (a frame on a reply id that no motor here sends, or that does not decode).
static int collect(fw_can* c, int check) {
  for (;;) {
    int k = first_pending(c);
    if (k < 0) return FW_OK;
    uint16_t id;
    uint8_t d[8], len;
    int got = take_or_wait(&id, d, &len);
    if (got < 0) return fault_at(c, k, FW_FAULT_TIMEOUT);
    if (!got) continue;
    k = route(c, id, d, len);
    if (k < 0) {
      int reply_id = 0;
      for (int i = 0; i < c->n; i++) reply_id |= c->motor[i].reply_id == id;
      if (reply_id) return fault_at(c, -1, FW_FAULT_CORRUPT);
      c->foreign++;
      continue;
    }
    const fw_can_motor* m = &c->motor[k];
    if (!c->pending[k]) continue;                      // a late answer: the state it had then
    if (m->dialect == FW_CAN_DAMIAO && (d[2] == CM_REG_READ || d[2] == CM_REG_WRITE) &&
        (uint16_t)(d[0] | d[1] << 8) == m->id)
      continue;                                        // a register echo, not a state
    cm_reply y;
    if (unpack(m, d, len, &y) != CM_OK) return fault_at(c, k, FW_FAULT_CORRUPT);
    c->pending[k] = 0;
    c->state[k] = y;
    c->effort[m->joint] = (int16_t)((d[4] & 0xFu) << 8 | d[5]);   // the torque (current) field, every dialect
    if (check && faulted(c, m, &y)) return fault_at(c, k, FW_FAULT_STATUS);
  }
}

static void drain(void) {
  uint16_t id;
  uint8_t d[8], len;
  for (int k = 0; k < 1000 && board_can_take(&id, d, &len); k++) {
  }
}

static int send(fw_can* c, int k, const uint8_t data[8]) {
  if (!board_can_send(c->motor[k].id, data, 8)) return fault_at(c, k, FW_FAULT_TIMEOUT);
  c->pending[k] = 1;
  return FW_OK;
}

static int special_all(fw_can* c, uint8_t code) {
  uint8_t data[8];
  cm_pack_special(data, code);
  for (int k = 0; k < c->n; k++) {
    int err = send(c, k, data);
    if (err) return err;
  }
  return FW_OK;
}

// One register transaction with Damiao motor k (hal/can/link.py's register): the frame on 0x7FF,
// its echo on the motor's reply id naming its CAN ID, the command and the register; other frames
// are dropped. 0 (*value: the echo's), or FW_FAULT_TIMEOUT.
static int reg(fw_can* c, int k, uint8_t cmd, uint8_t rid, uint32_t value, uint32_t* out) {
  const fw_can_motor* m = &c->motor[k];
  cm_register g = {.can_id = m->id, .cmd = cmd, .rid = rid, .value = value};
  uint8_t d[8], len;
  cm_pack_register(&g, d);
  if (!board_can_send(CM_DAMIAO_REGISTER_ID, d, 8)) return fault_at(c, k, FW_FAULT_TIMEOUT);
  for (;;) {
    uint16_t id;
    int got = take_or_wait(&id, d, &len);
    if (got < 0) return fault_at(c, k, FW_FAULT_TIMEOUT);
    if (!got) continue;
    if (id == m->reply_id && len == 8 && cm_unpack_register(d, len, &g) == CM_OK && g.can_id == m->id &&
        g.cmd == cmd && g.rid == rid) {
      *out = g.value;
      return FW_OK;
    }
  }
}

// a range register against the configuration's (hal/can/dialects.py's range_matches: float32 aside)
static int range_matches(uint32_t bits, cm_real want) {
  float got;
  memcpy(&got, &bits, 4);
  cm_real diff = (cm_real)got - want, scale = (cm_real)got < 0 ? -(cm_real)got : (cm_real)got;
  return (diff < 0 ? -diff : diff) <= CM_R(1e-4) * (scale > 1 ? scale : CM_R(1.0));
}

// A Damiao motor as hal/can/backend.py opens it: in MIT mode (in any other it ignores MIT frames
// without a word), PMAX / VMAX / TMAX the configuration's ranges (else every frame is scaled
// wrong), and its CAN timeout written. FW_FAULT_SETUP names the joint of one that is not so.
static int check_damiao(fw_can* c, int k) {
  const cm_ranges* r = &c->motor[k].ranges;
  const cm_real want[3] = {r->p_max, r->v_max, r->t_max};
  uint32_t v = 0;
  int err = reg(c, k, CM_REG_READ, DAMIAO_REG_CTRL_MODE, 0, &v);
  if (err) return err;
  if (v != DAMIAO_MIT_MODE) return fault_at(c, k, FW_FAULT_SETUP);
  for (int i = 0; i < 3; i++) {
    err = reg(c, k, CM_REG_READ, (uint8_t)(DAMIAO_REG_PMAX + i), 0, &v);
    if (err) return err;
    if (!range_matches(v, want[i])) return fault_at(c, k, FW_FAULT_SETUP);
  }
  return reg(c, k, CM_REG_WRITE, DAMIAO_REG_TIMEOUT, DAMIAO_TIMEOUT_UNITS, &v);
}

//---------------------------------- the bus ----------------------------------------------------

int fw_can_setup(fw_can* c) {
  c->torque_on = 0;
  c->fault_joint = -1;
  for (int k = 0; k < c->n; k++) c->pending[k] = 0;
  drain();                                             // late answers of an earlier run
  int err = FW_OK;
  for (int k = 0; k < c->n && err == FW_OK; k++)
    if (c->motor[k].dialect == FW_CAN_DAMIAO) err = check_damiao(c, k);
  if (err == FW_OK) err = special_all(c, CM_EXIT);
  if (err == FW_OK) err = collect(c, 1);
  // the answers to "enter" may carry the state before the frame (the mit firmware answers first):
  // a disabled status there is no fault (torque is not on until every motor answered)
  if (err == FW_OK) err = special_all(c, CM_ENTER);
  if (err == FW_OK) err = collect(c, 1);
  if (err == FW_OK) c->torque_on = 1;
  return err;
}

int fw_can_read(fw_can* c, sd_real* q, sd_real* qd, sd_real* current) {
  if (first_pending(c) < 0) {                          // no command since the last read: ask again
    int err = special_all(c, c->torque_on ? CM_ENTER : CM_EXIT);
    if (err) return err;
  }
  int err = collect(c, 1);
  if (err) return err;
  for (int k = 0; k < c->n; k++) {
    const fw_can_motor* m = &c->motor[k];
    const fw_servo* s = &c->servo[m->joint];
    sd_real scale = s->direction * s->gear_ratio;
    const cm_reply* y = &c->state[k];
    q[m->joint] = (y->p - s->zero_offset) / scale;
    qd[m->joint] = y->v / scale;
    current[m->joint] = y->t * scale / s->nm_per_amp;
  }
  return FW_OK;
}

int fw_can_write(fw_can* c, const sd_real* tau, int16_t* goal, int* limited) {
  for (int k = 0; k < c->n; k++) {
    const fw_can_motor* m = &c->motor[k];
    const fw_servo* s = &c->servo[m->joint];
    sd_real scale = s->direction * s->gear_ratio;
    cm_command cmd = {.p = s->zero_offset, .v = 0, .kp = 0, .kd = 0, .t = tau[m->joint] / scale};
    uint8_t data[8];
    unsigned clamped = 0;
    if (cm_pack_command(&m->ranges, &cmd, data, &clamped) != CM_OK) return fault_at(c, k, FW_FAULT_NONFINITE);
    *limited |= (clamped & CM_CLAMP_T) != 0;
    goal[m->joint] = (int16_t)((data[6] & 0xFu) << 8 | data[7]);
    int err = send(c, k, data);
    if (err) return err;
  }
  return FW_OK;
}

void fw_can_torque_off(fw_can* c) {
  c->torque_on = 0;
  // the answers still owed first (the last command's), so that each motor's next answer is its
  // answer to "exit": when they are all in, every motor has left motor mode
  collect(c, 0);
  if (special_all(c, CM_EXIT) == FW_OK) collect(c, 0);
  for (int k = 0; k < c->n; k++) c->pending[k] = 0;
}
