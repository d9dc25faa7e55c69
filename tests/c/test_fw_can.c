// test_fw_can.c: the general application's CAN bus (firmware/app/fw_can.c) on a fake board whose
// motors answer as the dialects do (hal/can/dialects.py), packed by the MIT codec itself: the
// set-up's frames, a tick's read and write in joint units and codes, the answers routed by id and
// length, and the faults (a silent motor, a fault status, a corrupt answer), each naming its joint.
#include <string.h>

#include "canmotor.h"
#include "fw_can.h"
#include "harness.h"

typedef struct {
  uint16_t id;
  uint8_t len, data[8];
} tframe;

enum { MAX_FRAMES = 128 };

// the fake bus: what the application sent, what waits for it, and the motors behind it
static tframe g_sent[MAX_FRAMES], g_wait[MAX_FRAMES];
static int g_nsent, g_head, g_nwait;
typedef struct {
  uint16_t id, reply_id;
  uint8_t dialect, status, enabled, silent;
  cm_ranges ranges;
  uint32_t mode, timeout;              // Damiao's CTRL_MODE and TIMEOUT registers
  cm_real p, v, t;                     // the state it reports
} tmotor;
static tmotor g_motor[4];
static int g_nmotor;

static void queue(uint16_t id, const uint8_t* d, uint8_t len) {
  if (g_head + g_nwait >= MAX_FRAMES) return;
  tframe* f = &g_wait[g_head + g_nwait++];
  f->id = id, f->len = len;
  memcpy(f->data, d, len);
}

// a motor's answer to a frame: Damiao reports the new state after enter/exit; mit and CubeMars pack
// their answer first, so a fault status of CubeMars (its error byte) shows in every answer
static void answer(tmotor* m) {
  uint8_t out[8];
  cm_reply y = {.id = (uint8_t)m->id, .p = m->p, .v = m->v, .t = m->t};
  if (m->dialect == FW_CAN_DAMIAO) {
    y.status = m->status ? m->status : m->enabled;
    cm_pack_damiao_feedback(&m->ranges, &y, out);
    queue(m->reply_id, out, 8);
  } else if (m->dialect == FW_CAN_MIT) {
    cm_pack_mit_reply(&m->ranges, &y, out);
    queue(m->reply_id, out, 6);
  } else {
    y.status = m->status;
    cm_pack_cubemars_reply(&m->ranges, &y, out);
    queue(m->reply_id, out, 8);
  }
}

int board_can_open(uint32_t bitrate) { return bitrate == 1000000; }

// a Damiao register frame: the echo of a read (CTRL_MODE, PMAX/VMAX/TMAX as float32) or a write
static void registers(const uint8_t* data) {
  cm_register g;
  if (cm_unpack_register(data, 8, &g) != CM_OK) return;
  for (int k = 0; k < g_nmotor; k++) {
    tmotor* m = &g_motor[k];
    if (m->dialect != FW_CAN_DAMIAO || m->id != g.can_id || m->silent) continue;
    if (g.cmd == CM_REG_WRITE && g.rid == 9) m->timeout = g.value;
    if (g.cmd == CM_REG_READ) {
      float range = g.rid == 21 ? (float)m->ranges.p_max : g.rid == 22 ? (float)m->ranges.v_max
                                                                        : (float)m->ranges.t_max;
      if (g.rid == 10) g.value = m->mode;
      else memcpy(&g.value, &range, 4);
    }
    uint8_t out[8];
    cm_pack_register(&g, out);
    queue(m->reply_id, out, 8);
  }
}

int board_can_send(uint16_t id, const uint8_t* data, uint8_t len) {
  if (g_nsent < MAX_FRAMES) {
    g_sent[g_nsent].id = id, g_sent[g_nsent].len = len;
    memcpy(g_sent[g_nsent++].data, data, len);
  }
  if (id == CM_DAMIAO_REGISTER_ID && len == 8) {
    registers(data);
    return 1;
  }
  for (int k = 0; k < g_nmotor; k++) {
    tmotor* m = &g_motor[k];
    if (m->id != id || len != 8) continue;
    int code = cm_special(data, len);
    if (code == CM_ENTER) m->enabled = 1;
    if (code == CM_EXIT) m->enabled = 0;
    if (!m->silent) answer(m);
  }
  return 1;
}

int board_can_take(uint16_t* id, uint8_t* data, uint8_t* len) {
  if (!g_nwait) return 0;
  tframe* f = &g_wait[g_head++];
  g_nwait--;
  *id = f->id, *len = f->len;
  memcpy(data, f->data, f->len);
  if (!g_nwait) g_head = 0;
  return 1;
}

int board_can_wait(void) { return g_nwait > 0; }   // nothing comes later on the fake bus
void board_clock_hold(void) {}
void board_clock_release(void) {}

static const cm_ranges DM4340 = {CM_R(12.5), CM_R(8.0), CM_R(28.0), CM_R(500.0), CM_R(5.0)};
static fw_servo g_servo[4];

// joints 0 and 2 Dynamixel (not on this bus), joint 1 a Damiao DM-J4340 (id 2, answers on 0x12,
// direction -1, gear 2, zero 0.5 rad), joint 3 a mit motor (id 4, answers on 0)
static void arm(fw_can* c) {
  memset(g_servo, 0, sizeof g_servo);
  memset(g_motor, 0, sizeof g_motor);
  g_nsent = g_nwait = g_head = 0;
  for (int i = 0; i < 4; i++) {
    g_servo[i].direction = 1, g_servo[i].gear_ratio = 1, g_servo[i].nm_per_amp = SD_R(4.0);
    g_servo[i].can = i % 2 == 1;
  }
  g_servo[1].direction = -1, g_servo[1].gear_ratio = 2, g_servo[1].zero_offset = SD_R(0.5);
  g_motor[0] = (tmotor){.id = 2, .reply_id = 0x12, .dialect = FW_CAN_DAMIAO, .ranges = DM4340, .mode = 1};
  g_motor[1] = (tmotor){.id = 4, .reply_id = 0, .dialect = FW_CAN_MIT, .ranges = DM4340};
  g_nmotor = 2;
  fw_can_init(c, g_servo);
  const sd_real range[5] = {SD_R(12.5), SD_R(8.0), SD_R(28.0), SD_R(500.0), SD_R(5.0)};
  fw_can_add(c, 1, 2, 0x12, FW_CAN_DAMIAO, range);
  fw_can_add(c, 3, 4, 0, FW_CAN_MIT, range);
}

static void setup_exits_then_enters_every_motor(void) {
  static fw_can c;
  arm(&c);
  EXPECT_INT(fw_can_setup(&c), FW_OK, "both motors answer exit, then enter");
  EXPECT_INT(g_nsent, 5 + 4, "the Damiao motor's 5 register frames, then one exit and one enter frame a motor");
  int regs = 0;
  for (int k = 0; k < 5; k++) regs += g_sent[k].id == CM_DAMIAO_REGISTER_ID;
  EXPECT_INT(regs * 100000 + g_motor[0].timeout, 5 * 100000 + 2000, "CTRL_MODE, PMAX, VMAX, TMAX read; TIMEOUT 0.1 s");
  EXPECT_INT(cm_special(g_sent[5].data, 8) * 1000 + g_sent[5].id, CM_EXIT * 1000 + 2, "exit to motor 2 first");
  EXPECT_INT(cm_special(g_sent[6].data, 8) * 1000 + g_sent[6].id, CM_EXIT * 1000 + 4, "then to motor 4");
  EXPECT_INT(cm_special(g_sent[7].data, 8) + cm_special(g_sent[8].data, 8), 2 * CM_ENTER, "then enter, both");
  EXPECT_INT(c.torque_on * 10 + g_motor[0].enabled + g_motor[1].enabled, 12, "torque on, both in motor mode");

  arm(&c);
  g_motor[0].mode = 2;                             // position-velocity: MIT frames ignored
  EXPECT_INT(fw_can_setup(&c) * 10 + c.fault_joint, FW_FAULT_SETUP * 10 + 1, "not in MIT mode: set-up fault, its joint");
  EXPECT_INT(g_motor[0].enabled + g_motor[1].enabled, 0, "before any motor enters motor mode");
  arm(&c);
  g_motor[0].ranges.t_max = CM_R(10.0);
  EXPECT_INT(fw_can_setup(&c) * 10 + c.fault_joint, FW_FAULT_SETUP * 10 + 1, "TMAX 10 where 28 is configured");
  arm(&c);
  g_motor[0].silent = 1;
  EXPECT_INT(fw_can_setup(&c) * 10 + c.fault_joint, FW_FAULT_TIMEOUT * 10 + 1, "no register echo: a timeout");
}

static void a_tick_reads_joint_units_and_writes_torque_codes(void) {
  static fw_can c;
  arm(&c);
  fw_can_setup(&c);
  g_motor[0].p = CM_R(1.5), g_motor[0].v = CM_R(-2.0), g_motor[0].t = CM_R(3.0);
  g_motor[1].p = CM_R(-0.25), g_motor[1].v = CM_R(1.0), g_motor[1].t = CM_R(-1.0);
  sd_real q[4] = {9, 9, 9, 9}, qd[4] = {9, 9, 9, 9}, cur[4] = {9, 9, 9, 9};
  int sent = g_nsent;
  EXPECT_INT(fw_can_read(&c, q, qd, cur), FW_OK, "no answer owed: enter again, and read them");
  EXPECT_INT(g_nsent - sent, 2, "one enter frame a motor");
  // the 16-bit position over +-12.5 rad: 3.8e-4 rad a code; the 12-bit speed over +-8: 3.9e-3 rad/s
  EXPECT_NEAR(q[1], (1.5 - 0.5) / -2.0, 2e-4, "q = (p - zero_offset) / (direction gear)");
  EXPECT_NEAR(qd[1], -2.0 / -2.0, 2e-3, "qd = v / (direction gear)");
  EXPECT_NEAR(cur[1], 3.0 * -2.0 / 4.0, 0.014, "current = t direction gear / nm_per_amp (a torque code 0.0137 N m)");
  EXPECT_NEAR(q[3] + qd[3], -0.25 + 1.0, 3e-3, "the mit motor's joint");
  EXPECT_NEAR(q[0] + q[2] + qd[0] + cur[2], 36, 0, "the Dynamixel joints untouched");
  EXPECT_INT(c.effort[1], (int)cm_to_uint(CM_R(3.0), -CM_R(28.0), CM_R(28.0), 12), "effort: the answer's torque code");

  sd_real tau[4] = {0, SD_R(-4.0), 0, SD_R(100.0)};
  int16_t goal[4] = {0};
  int limited = 0;
  sent = g_nsent;
  EXPECT_INT(fw_can_write(&c, tau, goal, &limited), FW_OK, "commands out");
  EXPECT_INT(g_nsent - sent, 2, "one command frame a motor, no waiting");
  cm_command cmd;
  EXPECT_INT(cm_unpack_command(&DM4340, g_sent[sent].data, 8, &cmd), CM_OK, "a command frame");
  EXPECT_NEAR(cmd.t, -4.0 / -2.0, 0.014, "t = tau / (direction gear)");
  EXPECT_NEAR(cmd.p, 0.5, 4e-4, "p = zero_offset");
  EXPECT_NEAR(cmd.kp + cmd.kd + cmd.v * 0, 0, 0, "torque alone: kp = kd = 0");
  EXPECT_INT(goal[1], (int)cm_to_uint(CM_R(2.0), -CM_R(28.0), CM_R(28.0), 12), "goal: the frame's torque code");
  EXPECT_INT(goal[3] * 10 + limited, 4095 * 10 + 1, "100 N m clamped at t_max: the top code, limiting");

  sent = g_nsent;
  EXPECT_INT(fw_can_read(&c, q, qd, cur), FW_OK, "the next tick reads the answers to the commands");
  EXPECT_INT(g_nsent - sent, 0, "without sending");
}

static void faults_name_their_joint(void) {
  static fw_can c;
  sd_real q[4], qd[4], cur[4];
  arm(&c);
  fw_can_setup(&c);
  g_motor[1].silent = 1;
  EXPECT_INT(fw_can_read(&c, q, qd, cur), FW_FAULT_TIMEOUT, "a motor that does not answer");
  EXPECT_INT(c.fault_joint, 3, "names its joint");

  arm(&c);
  fw_can_setup(&c);
  g_motor[0].status = 0xA;                       // Damiao: overcurrent
  EXPECT_INT(fw_can_read(&c, q, qd, cur), FW_FAULT_STATUS, "a fault status");
  EXPECT_INT(c.fault_joint, 1, "names its joint");

  sd_real tau[4] = {0};
  int16_t goal[4];
  int limited = 0;
  arm(&c);
  fw_can_setup(&c);
  g_motor[0].enabled = 0;                          // it left motor mode by itself (its CAN timeout)
  fw_can_write(&c, tau, goal, &limited);
  EXPECT_INT(fw_can_read(&c, q, qd, cur) * 10 + c.fault_joint, FW_FAULT_STATUS * 10 + 1,
             "Damiao disabled while torque is on: a fault, its joint");

  arm(&c);
  fw_can_setup(&c);
  fw_can_write(&c, tau, goal, &limited);           // answers owed
  fw_can_torque_off(&c);
  EXPECT_INT(g_motor[0].enabled + g_motor[1].enabled + c.torque_on, 0, "torque off: both out of motor mode");
  EXPECT_INT(cm_special(g_sent[g_nsent - 1].data, 8) + cm_special(g_sent[g_nsent - 2].data, 8), 2 * CM_EXIT,
             "the last frames: exit");
  EXPECT_INT(g_nwait, 0, "every answer taken, the owed ones first");

  arm(&c);
  fw_can_setup(&c);
  const uint8_t stray[8] = {0x03, 0, 0, 0, 0, 0, 0, 0};   // on 0x12, naming motor 3: none here
  fw_can_write(&c, tau, goal, &limited);
  g_nwait = 0, g_head = 0;
  queue(0x12, stray, 8);
  EXPECT_INT(fw_can_read(&c, q, qd, cur), FW_FAULT_CORRUPT, "a frame on a reply id that no motor here sends");

  arm(&c);
  fw_can_setup(&c);
  fw_can_write(&c, tau, goal, &limited);
  queue(0x123, stray, 8);                          // after the answers: another node's frame
  EXPECT_INT(fw_can_read(&c, q, qd, cur), FW_OK, "a frame on another id is skipped");
  EXPECT_INT(fw_can_read(&c, q, qd, cur) * 10 + (int)c.foreign, 1, "and counted");
}

static void a_cubemars_error_byte_is_a_fault(void) {
  static fw_can c;
  sd_real q[4], qd[4], cur[4];
  arm(&c);
  g_motor[1].dialect = FW_CAN_CUBEMARS, g_motor[1].reply_id = 0;
  c.motor[1].dialect = FW_CAN_CUBEMARS;
  EXPECT_INT(fw_can_setup(&c), FW_OK, "a CubeMars motor's 8-byte answers on 0 are routed");
  g_motor[1].status = 2;                           // over-current
  EXPECT_INT(fw_can_read(&c, q, qd, cur) * 10 + c.fault_joint, FW_FAULT_STATUS * 10 + 3, "its error byte");
}

const sdt_test sdt_fw_can_tests[] = {
  {"setup_exits_then_enters_every_motor", setup_exits_then_enters_every_motor},
  {"a_tick_reads_joint_units_and_writes_torque_codes", a_tick_reads_joint_units_and_writes_torque_codes},
  {"faults_name_their_joint", faults_name_their_joint},
  {"a_cubemars_error_byte_is_a_fault", a_cubemars_error_byte_is_a_fault},
  {0, 0},
};
