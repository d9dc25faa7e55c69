// fw_link.c: the general firmware application: any robot and any motion, sent at run time over the
// host link (firmware/link, docs/host-link.md), on Dynamixel servos (a UART, fw_bus.c) and CAN
// motors (the board's CAN controller, fw_can.c: the MIT codec), both in one tick for a mixed arm.
//
// It boots idle with no robot. Every control period (one tick):
//   1. the host's bytes: each good frame feeds the watchdog; requests are executed in order under
//      the retransmit rule (link_server) and answered: HELLO (version, board, precision, the
//      compiled sizes), LOAD_ROBOT / LOAD_BODY / LOAD_JOINT / COMMIT (the robot checked with the
//      core's checks by link_robot; once committed it is the controller's model and servo map),
//      KNOTS (into the knot ring, link_ring) and COMMAND (home, play, hold, stop, torque off, clear
//      a fault, telemetry); a frame of another version is answered with code -11;
//   2. the watchdog: the host silent host_timeout_ms (LOAD_ROBOT) while torque is on: hold the
//      desired pose from this tick on, and torque off reaction_time later;
//   3. with torque on (homing, playing, holding): the fast sync read of the Dynamixel servos and the
//      CAN motors' answers to the last tick's frames, the desired state (homing:
//      the minimum-jerk move to the motion's first knot; playing: the quintic between the ring's
//      two knots around the motion's time, sd_trajectory_segment, the core's interpolation, and
//      the knots' gains, linear between; holding: the pose at rest), then the controller step of
//      fw_main.c (fw_step.c: observer, feed-forward + PD + friction, the guards), the sync write
//      of Goal Current and each CAN motor's command frame. Any fault switches torque off (on both
//      buses) and waits in the fault state for the host;
//   4. TELEMETRY every N ticks (COMMAND telemetry N; 1 from HELLO on).
// A tick that finds the ring without the knot after the motion's time holds the last knot and
// sets STARVED: the motion's clock waits for the host. Past the last knot it holds it (DONE).
//
// Command line (the board's, for tests): ticks=N (stop after N ticks: torque off, the report line),
// once=1 (stop when torque goes off after a run: a fault, STOP, TORQUE_OFF, the watchdog),
// period_us=N (the clock's period instead of the robot's, the robot's own dt kept), tolerance_us=N
// (a host OS: how far the loop may fall behind before the overrun fault, default none: the host
// passes its OVERRUN_TOLERANCE), baud=N
// (the Dynamixel bus, default 1000000), can_bitrate=N (the CAN bus, default 1000000; the board's
// CAN controller, if it has one, is opened at boot and HELLO_REPLY says so). The report line's
// worst_work: the clock counts of the worst tick that began with torque on, the link's work
// included (instructions under QEMU's -icount).
#include <string.h>

#include "board.h"
#include "fw_app.h"
#include "fw_can.h"
#include "link.h"

#ifndef FW_LINK_BOARD
#define FW_LINK_BOARD "posix"            // the board's name in HELLO_REPLY
#endif
#ifndef FW_TOLERATE_OVERRUN
#define FW_TOLERATE_OVERRUN 0            // 1: a host OS: a late tick is counted, not a fault
#endif
#define FW_DEFAULT_PERIOD_US 1000u       // the idle clock, before a robot gives its period

typedef struct fw_link_app_ {
  link_decoder decoder;
  link_server server;
  link_robot robot;
  link_ring ring;
  fw_servo servo[SD_MAX_DOF];
  fw_guards guards;
  fw_step step;
  fw_bus bus;                          // the Dynamixel servos: ndxl of the joints
  fw_servo dxl_servo[SD_MAX_DOF];      // their fw_servo, in bus order
  int dxl_joint[SD_MAX_DOF];           // the joint of each
  int ndxl;
  fw_can can;                          // the CAN motors (can.n of the joints)
  uint8_t buses;                       // bit (1 << link_bus_) per bus the board drives
  int njoint;
  int state;                           // a link_state_
  int torque;                          // 1: torque on (homing, playing, holding)
  int fault, fault_joint;
  uint8_t seq;                         // the SEQ of the controller's next frame
  uint32_t telemetry_every;            // 0: none
  long tick;                           // ticks since boot
  long phase_tick;                     // ticks since the phase (homing, playing) began
  long home_ticks;
  int play_after_home;                 // PLAY came while homing
  uint32_t play_t0_us;                 // the motion's time at PLAY (its first knot's)
  long last_frame_tick;                // the watchdog: the tick of the host's last good frame
  long timeout_ticks, reaction_ticks, stop_ticks;   // watchdog, reaction; STOP's countdown (-1 none)
  long silent_hold_ticks;              // ticks held since the host fell silent (-1: not silent)
  int flags;                           // the tick's telemetry flags
  int done;                            // the motion played to its last knot (DONE until the next run)
  uint32_t period_us;
  sd_real dt;
  sd_real q[SD_MAX_DOF], qd[SD_MAX_DOF], current[SD_MAX_DOF];
  int16_t effort[SD_MAX_DOF], goal[SD_MAX_DOF];   // by joint: measured and commanded, servo units
  sd_real q_d[SD_MAX_DOF], qd_d[SD_MAX_DOF], qdd_d[SD_MAX_DOF];
  sd_real q_from[SD_MAX_DOF], q_hold[SD_MAX_DOF];
  uint32_t work, work_max;             // clock counts of the last tick's work; the worst of a tick
                                       // that began with torque on (homing, playing, holding)
  uint32_t link_max, control_max;      // of those ticks, the worst link work (requests, telemetry)
                                       // and the worst control work (bus, step)
  long control_max_tick;               // the tick of the worst control work
  uint64_t control_sum;                // control work of every running tick, for the mean
  long running_ticks;
  int once;                            // once=1: stop when torque goes off after a run (tests)
  long tolerance_us;                   // how far a host OS may fall behind (FW_TOLERATE_OVERRUN)
  long clock_period_us;                // period_us=N: the clock's period, not the robot's (measuring
                                       // under QEMU with a slow -icount clock); 0: the robot's
  int ran;                             // torque has been on
  long missed;
  long scheduled;                      // the clock period the next tick belongs to
  long stop_after;
  uint32_t frames_in, frames_bad, bytes_in, bytes_out, frames_dropped;
  uint8_t out[LINK_MAX_WIRE];
} fw_link_app;

static fw_link_app g;

//---------------------------------- the line ----------------------------------------------------

static void send(uint8_t type, const uint8_t* payload, size_t n) {
  size_t len = link_frame(g.out, sizeof g.out, g.seq, g.server.expected, type, payload, n);
  if (!len) return;
  g.seq++;
  if (board_link_write(g.out, len)) {
    g.bytes_out += (uint32_t)len;
  } else {
    g.frames_dropped++;
  }
}

static void send_result(const link_result* r) {
  uint8_t p[16];
  send(LINK_RESULT, p, link_pack_result(p, sizeof p, r));
}

//---------------------------------- torque and faults -------------------------------------------

static void torque_off(int state) {
  if (g.torque && g.ndxl) fw_bus_torque_off(&g.bus);
  if (g.torque && g.can.n) fw_can_torque_off(&g.can);
  g.torque = 0;
  g.state = state;
  g.stop_ticks = -1;
  g.silent_hold_ticks = -1;
}

// the joint of a Dynamixel servo (by its id on that bus), -1 none
static int dxl_joint_of(int id) {
  for (int k = 0; k < g.ndxl; k++)
    if (g.dxl_servo[k].id == id) return g.dxl_joint[k];
  return -1;
}

static void fault(int code, int joint) {
  g.fault = code;
  g.fault_joint = joint;
  torque_off(LINK_FAULT);
}

//---------------------------------- both buses --------------------------------------------------

// Each bus set up, torque on: 0, or a fault code (g.fault_joint's joint through fault())
static int buses_setup(int* joint) {
  int err = g.ndxl ? fw_bus_setup(&g.bus) : FW_OK;
  if (err) {
    *joint = dxl_joint_of(g.bus.fault_servo);
    return err;
  }
  err = g.can.n ? fw_can_setup(&g.can) : FW_OK;
  *joint = g.can.fault_joint;
  return err;
}

// Every joint's state, both buses. The CAN motors' answers first: when they are all in, the
// motors have taken the last tick's frames, so the Dynamixel read that follows sees whatever those
// frames started (a lock-stepped simulator advances its plant once both buses had their commands)
static int buses_read(int* joint) {
  if (g.can.n) {
    int err = fw_can_read(&g.can, g.q, g.qd, g.current);
    if (err) {
      *joint = g.can.fault_joint;
      return err;
    }
    for (int k = 0; k < g.can.n; k++) g.effort[g.can.motor[k].joint] = g.can.effort[g.can.motor[k].joint];
  }
  if (g.ndxl) {
    sd_real q[SD_MAX_DOF], qd[SD_MAX_DOF], current[SD_MAX_DOF];
    int err = fw_bus_read(&g.bus, q, qd, current);
    if (err) {
      *joint = dxl_joint_of(g.bus.fault_servo);
      return err;
    }
    for (int k = 0; k < g.ndxl; k++) {
      int i = g.dxl_joint[k];
      g.q[i] = q[k], g.qd[i] = qd[k], g.current[i] = current[k], g.effort[i] = g.bus.current_units[k];
    }
  }
  return FW_OK;
}

// The step's commands out, both buses: 0 or a fault code; *limited |= a CAN torque clamped
static int buses_write(int* limited, int* joint) {
  for (int i = 0; i < g.njoint; i++) g.goal[i] = g.step.goal[i];
  if (g.ndxl) {
    int16_t goal[SD_MAX_DOF];
    for (int k = 0; k < g.ndxl; k++) goal[k] = g.step.goal[g.dxl_joint[k]];
    fw_bus_write_goals(&g.bus, goal);
  }
  int err = g.can.n ? fw_can_write(&g.can, g.step.tau, g.goal, limited) : FW_OK;
  *joint = g.can.fault_joint;
  return err;
}

// hold the present desired pose, at rest, with the gains in force
static void hold_here(void) {
  for (int i = 0; i < g.njoint; i++) g.q_hold[i] = g.q_d[i];
  g.state = LINK_HOLDING;
}

//---------------------------------- requests ---------------------------------------------------

// COMMIT accepted: the robot becomes the controller's (its model, servo map, gains and guards)
static void install_robot(link_result* r) {
  const link_robot_head* h = &g.robot.head;
  if (h->free_root) {                      // every dof must be a servo or a motor
    r->stage = LINK_STAGE_SERVO, r->code = LINK_SERVO_BUS, r->index = 0;
    g.robot.ready = 0;
    return;
  }
  g.njoint = h->ndof;
  g.period_us = h->period_us;
  g.dt = (sd_real)h->period_us * SD_R(1e-6);
  for (int i = 0; i < g.njoint; i++) {
    const link_joint* j = &g.robot.joint[i];
    g.servo[i] = (fw_servo){.id = j->id, .model_number = j->model_number, .direction = j->direction,
                            .zero_offset = j->zero_offset, .gear_ratio = j->gear_ratio,
                            .rad_per_tick = j->rad_per_tick, .radps_per_unit = j->radps_per_unit,
                            .amp_per_unit = j->effort_per_unit, .nm_per_amp = j->nm_per_effort,
                            .current_limit = j->effort_limit, .q_min = j->q_min, .q_max = j->q_max,
                            .qd_max = j->qd_max, .friction_coulomb = j->friction_coulomb,
                            .friction_viscous = j->friction_viscous, .following_error = j->following_error,
                            .observer_gain = j->observer_gain, .observer_lowpass = j->observer_lowpass,
                            .contact_threshold = j->contact_threshold, .can = j->bus == LINK_BUS_CAN};
  }
  g.ndxl = 0;
  fw_can_init(&g.can, g.servo);
  for (int i = 0; i < g.njoint; i++) {
    const link_joint* j = &g.robot.joint[i];
    if (j->bus == LINK_BUS_CAN) {
      fw_can_add(&g.can, i, j->id, j->reply_id, j->dialect, j->mit_range);
    } else {
      g.dxl_servo[g.ndxl] = g.servo[i];
      g.dxl_joint[g.ndxl++] = i;
    }
  }
  // seconds -> ticks as servodyn codegen counts them (ceil, at least 1)
  sd_real eps = SD_R(1e-4);
  long stall = (long)(h->stall_time / g.dt - eps) + 1;
  long arm = (long)(h->contact_arm_time / g.dt - eps) + 1;
  g.guards = (fw_guards){.stall_ticks = stall < 1 ? 1 : stall, .stall_speed = h->stall_speed,
                         .stall_share = h->stall_share, .contact = h->contact,
                         .contact_debounce = h->contact_debounce, .contact_arm_ticks = arm < 1 ? 1 : arm};
  fw_step_init(&g.step, &g.robot.model, g.servo, g.njoint, &g.guards, g.dt, h->friction_speed);
  g.step.control = g.robot.control;        // mode, update_ticks, gains, limits, friction: checked
  g.step.oconfig = g.robot.observer;
  fw_bus_init(&g.bus, g.dxl_servo, g.ndxl);
  link_ring_reset(&g.ring, g.njoint, SD_MAX_KNOT);
  g.timeout_ticks = (long)h->host_timeout_ms * 1000 / (long)h->period_us;
  g.reaction_ticks = (long)(h->reaction_time / g.dt + SD_R(0.5));
  g.state = LINK_LOADED;
  g.fault = 0;
  g.fault_joint = -1;
  uint32_t clock_us = g.clock_period_us > 0 ? (uint32_t)g.clock_period_us : h->period_us;
  board_clock_start((uint32_t)((uint64_t)clock_us * BOARD_CPU_HZ / 1000000u));
  g.scheduled = 0;
}

// HOME: set the bus up when torque is off, read where the arm is, then the minimum-jerk move
static int command_home(uint32_t ms) {
  if (g.state < LINK_LOADED || g.state == LINK_FAULT || g.state == LINK_PLAYING || !g.ring.count)
    return LINK_E_STATE;
  int joint = -1;
  if (!g.torque) {
    int err = buses_setup(&joint);
    g.torque = 1;                          // some servos may have switched on: switch all off on a fault
    if (err) {
      fault(err, joint);
      return LINK_OK;                      // done, and faulted: the telemetry says why
    }
  }
  int err = buses_read(&joint);
  if (err) {
    fault(err, joint);
    return LINK_OK;
  }
  for (int i = 0; i < g.njoint; i++) g.q_from[i] = g.q[i];
  g.home_ticks = (long)((uint64_t)ms * 1000u / g.period_us) + 1;
  g.phase_tick = 0;
  g.play_after_home = 0;
  g.done = 0;
  g.stop_ticks = -1;
  for (int i = 0; i < g.njoint; i++) {
    g.step.control.kp[i] = g.robot.control.kp[i];
    g.step.control.kd[i] = g.robot.control.kd[i];
  }
  sd_control_reset(&g.step.cstate);
  fw_step_start(&g.step, g.q, g.qd);
  g.state = LINK_HOMING;
  return LINK_OK;
}

static void start_play(void) {
  g.play_t0_us = link_ring_at(&g.ring, 0)->t_us;
  g.phase_tick = 0;
  sd_control_reset(&g.step.cstate);
  g.state = LINK_PLAYING;
}

static int command(const link_command* c) {
  switch (c->command) {
    case LINK_CMD_KEEPALIVE:
      return LINK_OK;
    case LINK_CMD_HOME:
      return command_home(c->arg);
    case LINK_CMD_PLAY:                    // from the motion's first knot, once homed there
      if (!g.ring.count || g.ring.next - g.ring.count != 0) return LINK_E_STATE;
      if (g.state == LINK_HOMING) {
        g.play_after_home = 1;
      } else if (g.state == LINK_HOLDING && g.silent_hold_ticks < 0 && g.stop_ticks < 0) {
        start_play();
      } else {
        return LINK_E_STATE;
      }
      return LINK_OK;
    case LINK_CMD_HOLD:
      if (!g.torque) return LINK_E_STATE;
      if (g.state != LINK_HOLDING) hold_here();
      return LINK_OK;
    case LINK_CMD_STOP:                    // the safety table's reaction, then torque off
      if (!g.torque) return LINK_OK;
      if (g.robot.head.reaction == LINK_REACT_HOLD || g.robot.head.reaction == LINK_REACT_RETRACT) {
        if (g.state != LINK_HOLDING) hold_here();
        g.stop_ticks = g.reaction_ticks;
      } else {
        torque_off(LINK_TORQUE_OFF);
      }
      return LINK_OK;
    case LINK_CMD_TORQUE_OFF:
      if (g.state >= LINK_LOADED && g.state != LINK_FAULT) torque_off(LINK_TORQUE_OFF);
      return LINK_OK;
    case LINK_CMD_CLEAR_FAULT:
      if (g.state == LINK_FAULT) {
        g.fault = 0;
        g.fault_joint = -1;
        g.state = LINK_LOADED;
      }
      return LINK_OK;
    case LINK_CMD_TELEMETRY:
      g.telemetry_every = c->arg;
      return LINK_OK;
    default:
      return LINK_E_COMMAND;
  }
}

static void hello(uint8_t seq, const uint8_t* p, size_t n) {
  link_hello h;
  link_result r = {.seq = seq, .type = LINK_HELLO, .stage = LINK_STAGE_LINK, .index = -1};
  if (link_unpack_hello(p, n, &h) != LINK_OK) {
    r.code = LINK_E_PAYLOAD;
    link_server_done(&g.server, &r);
    send_result(&r);
    return;
  }
  link_server_done(&g.server, &r);
  link_hello_reply a = {.nonce = h.nonce, .link_version = LINK_VERSION, .fw_major = LINK_FW_MAJOR,
                        .fw_minor = LINK_FW_MINOR, .fw_patch = LINK_FW_PATCH, .real_bytes = sizeof(sd_real),
                        .max_body = SD_MAX_BODY, .max_dof = SD_MAX_DOF, .knot_slots = SD_MAX_KNOT,
                        .max_payload = LINK_MAX_PAYLOAD, .window = LINK_WINDOW, .buses = g.buses,
                        .state = (uint8_t)g.state};
  strncpy(a.board, FW_LINK_BOARD, sizeof a.board);
  if (!g.telemetry_every) g.telemetry_every = 1;
  uint8_t out[32];
  send(LINK_HELLO_REPLY, out, link_pack_hello_reply(out, sizeof out, &a));
}

static int running(void) { return g.state == LINK_HOMING || g.state == LINK_PLAYING || g.state == LINK_HOLDING; }

static void execute(uint8_t seq, uint8_t type, const uint8_t* p, size_t n) {
  if (type == LINK_HELLO) {
    hello(seq, p, n);
    return;
  }
  link_result r = {.seq = seq, .type = type, .stage = LINK_STAGE_LINK, .code = LINK_OK, .index = -1};
  switch (type) {
    case LINK_LOAD_ROBOT: {
      link_robot_head h;
      if (running()) {
        r.code = LINK_E_STATE;
      } else if (link_unpack_robot_head(p, n, &h) != LINK_OK) {
        r.code = LINK_E_PAYLOAD;
      } else {
        g.state = LINK_IDLE;               // the robot before is gone
        g.njoint = 0;
        g.done = 0;
        link_robot_begin(&g.robot, &h, &r);
      }
      break;
    }
    case LINK_LOAD_BODY: {
      link_body b;
      if (running()) r.code = LINK_E_STATE;
      else if (link_unpack_body(p, n, &b) != LINK_OK) r.code = LINK_E_PAYLOAD;
      else link_robot_body(&g.robot, &b, &r);
      break;
    }
    case LINK_LOAD_JOINT: {
      link_joint j;
      if (running()) r.code = LINK_E_STATE;
      else if (link_unpack_joint(p, n, &j) != LINK_OK) r.code = LINK_E_PAYLOAD;
      else link_robot_joint(&g.robot, &j, &r);
      break;
    }
    case LINK_COMMIT:
      if (running() || n != 0) {
        r.code = running() ? LINK_E_STATE : LINK_E_PAYLOAD;
      } else {
        link_robot_commit(&g.robot, g.buses, &r);
        if (r.code == LINK_OK && r.stage == LINK_STAGE_LINK) install_robot(&r);
      }
      break;
    case LINK_KNOTS:
      if (g.state == LINK_IDLE) r.code = LINK_E_STATE;
      else link_ring_push(&g.ring, p, n, &r);
      break;
    case LINK_COMMAND: {
      link_command c;
      r.code = (int8_t)(link_unpack_command(p, n, &c) != LINK_OK ? LINK_E_PAYLOAD : command(&c));
      break;
    }
    default:
      r.code = LINK_E_TYPE;
  }
  r.seq = seq;
  r.type = type;
  r.credits = g.state == LINK_IDLE ? 0 : link_ring_free(&g.ring);
  link_server_done(&g.server, &r);
  send_result(&r);
}

static void frame_in(const link_decoder* d) {
  g.frames_in++;
  g.last_frame_tick = g.tick;              // the watchdog: any good frame from the host
  if (g.silent_hold_ticks >= 0) g.silent_hold_ticks = -1;   // back: holding, no torque-off countdown
  link_result reply;
  switch (link_server_accept(&g.server, d->seq, d->type, &reply)) {
    case LINK_EXECUTE:
      execute(d->seq, d->type, d->payload, d->len);
      break;
    case LINK_REPEAT:
    case LINK_REFUSE:
      reply.credits = g.state == LINK_IDLE ? 0 : link_ring_free(&g.ring);
      send_result(&reply);
      break;
    default:
      break;
  }
}

// The host's bytes of this tick: at most FW_LINK_BYTES_PER_TICK, the rest waits in the line's
// receive buffer for the next ticks, so that a burst of requests (a window of KNOTS frames, up to
// 8 x 250 bytes) is decoded over many ticks instead of in one: a KNOTS frame's decoding (about 20
// instructions a byte) never lands whole on the inverse-dynamics tick. 64 bytes a tick is 0.64 Mbit/s
// at 1 kHz: a whole window sent back to back on a 2 Mbps line (10 ms) leaves at most 1,360 bytes
// waiting in the microcontroller's 2 KB receive ring (firmware/mcu/board_link_ring.h); the host's
// steady traffic (a knot as a credit frees, keepalives) is a small part of it.
#ifndef FW_LINK_BYTES_PER_TICK
#define FW_LINK_BYTES_PER_TICK 64u
#endif

static void poll_link(void) {
  uint8_t chunk[FW_LINK_BYTES_PER_TICK];
  size_t n = board_link_take(chunk, sizeof chunk);
  g.bytes_in += (uint32_t)n;
  for (size_t k = 0; k < n;) {
    size_t used;
    int v = link_decoder_feed_bytes(&g.decoder, chunk + k, n - k, &used);
    k += used;
    if (v == LINK_FRAME) {
      frame_in(&g.decoder);
    } else if (v == LINK_BAD_VERSION) {    // answered in this controller's version
      g.frames_bad++;
      link_result r = {.seq = g.decoder.seq, .type = g.decoder.type, .stage = LINK_STAGE_LINK,
                       .code = LINK_E_VERSION, .index = -1,
                       .credits = g.state == LINK_IDLE ? 0 : link_ring_free(&g.ring)};
      send_result(&r);
    } else if (v != LINK_MORE) {
      g.frames_bad++;
    }
  }
}

//---------------------------------- the desired state -------------------------------------------

// the minimum-jerk move of host/control/schedule.py's homing(): at rest at both ends
static void home_point(long k, const sd_real* to) {
  long n = g.home_ticks;
  sd_real duration = (sd_real)(n - 1) * g.dt;
  sd_real s = n > 1 ? (sd_real)k / (sd_real)(n - 1) : SD_R(1.0);
  sd_real s2 = s * s, s3 = s2 * s;
  sd_real blend = s3 * (SD_R(10.0) - SD_R(15.0) * s + SD_R(6.0) * s2);
  sd_real rate = n > 1 ? s2 * (SD_R(30.0) - SD_R(60.0) * s + SD_R(30.0) * s2) / duration : 0;
  sd_real accel = n > 1 ? s * (SD_R(60.0) - SD_R(180.0) * s + SD_R(120.0) * s2) / (duration * duration) : 0;
  for (int i = 0; i < g.njoint; i++) {
    sd_real delta = to[i] - g.q_from[i];
    g.q_d[i] = g.q_from[i] + blend * delta;
    g.qd_d[i] = rate * delta;
    g.qdd_d[i] = accel * delta;
  }
}

static void at_rest(const sd_real* q) {
  for (int i = 0; i < g.njoint; i++) g.q_d[i] = q[i], g.qd_d[i] = g.qdd_d[i] = 0;
}

// the motion at its time: the ring's knots behind it go; the quintic of the two around it, and
// the knots' gains linear between (zero gains: the robot's own). 0, or 1 when the tick holds.
static int play_point(int update) {
  uint32_t t_us = g.play_t0_us + (uint32_t)((uint64_t)g.phase_tick * g.period_us);
  while (g.ring.count >= 2 && link_ring_at(&g.ring, 1)->t_us <= t_us) link_ring_pop(&g.ring);
  const link_knot* k0 = link_ring_at(&g.ring, 0);
  const link_knot* k1 = link_ring_at(&g.ring, 1);
  if (!k1) {                               // the last knot: done, or the host is late
    at_rest(k0->q);
    if (g.ring.ended && !g.done)           // the motion's last tick: its end as written (moving or not)
      for (int i = 0; i < g.njoint; i++) g.qd_d[i] = k0->qd[i], g.qdd_d[i] = k0->qdd[i];
    if (g.ring.ended) g.done = 1;
    else g.flags |= LINK_TM_STARVED;
    if (update && k0->kp[0] != 0) {        // its gains, as a schedule holds its last knot's
      for (int i = 0; i < g.njoint; i++) g.step.control.kp[i] = k0->kp[i], g.step.control.kd[i] = k0->kd[i];
    }
    return 1;
  }
  // the segment's own clock, from its first knot, in whole microseconds: exact however long the
  // motion (the motion's clock in single precision would lose a microsecond past 16 s)
  sd_real t0 = 0;
  sd_real t1 = (sd_real)(k1->t_us - k0->t_us) * SD_R(1e-6);
  sd_real t = (sd_real)(t_us - k0->t_us) * SD_R(1e-6);
  sd_trajectory_segment(g.njoint, t0, t1, k0->q, k0->qd, k0->qdd, k1->q, k1->qd, k1->qdd, t, g.q_d, g.qd_d,
                        g.qdd_d);
  if (update && k0->kp[0] != 0) {
    sd_real w = (t - t0) / (t1 - t0);
    w = w < 0 ? 0 : (w > 1 ? SD_R(1.0) : w);
    for (int i = 0; i < g.njoint; i++) {
      g.step.control.kp[i] = k0->kp[i] + w * (k1->kp[i] - k0->kp[i]);
      g.step.control.kd[i] = k0->kd[i] + w * (k1->kd[i] - k0->kd[i]);
    }
  }
  return 0;
}

//---------------------------------- the tick ----------------------------------------------------

static void watchdog(void) {
  if (!g.torque || g.timeout_ticks <= 0) return;
  if (g.silent_hold_ticks < 0 && g.tick - g.last_frame_tick >= g.timeout_ticks) {
    g.silent_hold_ticks = 0;               // hold from this tick on, torque off reaction_time later
    if (g.state != LINK_HOLDING) hold_here();
  }
  if (g.silent_hold_ticks >= 0) {
    g.flags |= LINK_TM_HOST_SILENT;
    if (g.silent_hold_ticks++ >= g.reaction_ticks) torque_off(LINK_TORQUE_OFF);
  }
}

static void control_tick(void) {
  int joint = -1;
  int err = buses_read(&joint);
  if (err) {
    fault(err, joint);
    return;
  }
  if (g.state == LINK_HOMING && g.phase_tick >= g.home_ticks) {   // homed: this tick plays or holds
    if (g.play_after_home) {
      start_play();
    } else {
      at_rest(link_ring_at(&g.ring, 0)->q);
      hold_here();
    }
  }
  int update = g.phase_tick % g.step.control.update_ticks == 0;
  if (g.state == LINK_HOMING) {
    home_point(g.phase_tick, link_ring_at(&g.ring, 0)->q);
  } else if (g.state == LINK_PLAYING) {
    if (play_point(update)) {
      if (g.ring.ended) hold_here();       // done: hold the last knot
      g.phase_tick--;                      // starved: the motion's clock waits for the host
    }
  } else {
    at_rest(g.q_hold);
  }
  int limited = fw_step_clamp_plan(&g.step, g.q_d, g.qd_d, g.qdd_d);
  fw_step_observe(&g.step, g.q, g.qd, g.current);
  err = fw_step_control(&g.step, g.q_d, g.qd_d, g.qdd_d, g.q, g.qd);
  if (err == FW_OK) err = fw_step_finish(&g.step, g.q_d, g.q, g.qd, &limited);
  if (err) {
    fault(err, g.step.fault_joint);
    return;
  }
  err = buses_write(&limited, &joint);
  if (err) {
    fault(err, joint);
    return;
  }
  if (limited) g.flags |= LINK_TM_LIMITED;
  fw_record_tick(g.tick, g.njoint, g.q_d, g.q, g.qd, g.step.tau, g.current);
  g.phase_tick++;
  if (g.stop_ticks >= 0 && g.stop_ticks-- == 0) torque_off(LINK_TORQUE_OFF);
}

// The tick's heavy part: its control step runs the inverse dynamics (sd_control_step's rule: every
// update_ticks-th step since the controller's reset, or after a refused one), or it starts the
// motion, which resets the controller. Known before the tick's work, so the link's own work keeps
// off it: that tick takes none of the host's bytes, and decimated telemetry waits a tick.
static int heavy_tick(void) {
  if (!g.torque) return 0;
  if (g.state == LINK_HOMING && g.phase_tick >= g.home_ticks && g.play_after_home) return 1;
  return g.step.cstate.refresh || g.step.cstate.tick % g.step.control.update_ticks == 0;
}

// Telemetry every telemetry_every ticks: every tick (the host's log needs them all), or, decimated
// (N > 1), N ticks after the last frame, postponed past a heavy tick; then that tick takes none of
// the host's bytes either. 1: this tick sends it.
static uint32_t g_since_telemetry;     // ticks since the last frame (decimated)

static int telemetry_due(int heavy) {
  if (!g.telemetry_every) return 0;
  return g.telemetry_every == 1 || (g_since_telemetry + 1 >= g.telemetry_every && !heavy);
}

static void telemetry(int due) {
  g_since_telemetry++;
  if (!due) return;
  g_since_telemetry = 0;
  static link_telemetry t;
  t.tick = (uint32_t)g.tick;
  uint64_t us = (uint64_t)g.work * 1000000u / BOARD_CPU_HZ;
  t.work_us = (uint16_t)(us > 65535u ? 65535u : us);
  t.missed = (uint16_t)(g.missed > 65535 ? 65535 : g.missed);
  t.state = (uint8_t)g.state;
  t.fault = (uint8_t)g.fault;
  t.fault_joint = (uint8_t)(g.fault_joint < 0 ? 255 : g.fault_joint);
  t.flags = (uint8_t)(g.flags | (g.done ? LINK_TM_DONE : 0));
  t.credits = g.state == LINK_IDLE ? 0 : link_ring_free(&g.ring);
  t.njoint = (uint8_t)(g.njoint < LINK_MAX_TELEMETRY_JOINT ? g.njoint : LINK_MAX_TELEMETRY_JOINT);
  for (int i = 0; i < t.njoint; i++) {
    link_joint_tm* j = &t.joint[i];
    j->q = g.q[i], j->qd = g.qd[i], j->q_d = g.q_d[i], j->tau = g.step.tau[i];
    j->effort = g.effort[i];
    j->command = g.goal[i];
    j->residual = g.step.observer.rf[i];
  }
  uint8_t p[LINK_MAX_PAYLOAD];
  send(LINK_TELEMETRY, p, link_pack_telemetry(p, sizeof p, &t));
}

static long arg_value(const char* line, const char* key, long fallback) {
  const char* p = strstr(line, key);
  if (!p) return fallback;
  p += strlen(key);
  long value = 0;
  while (*p >= '0' && *p <= '9') value = value * 10 + (*p++ - '0');
  return value;
}

static void report(void) {
  board_write("servodyn-fw: ");
  board_write(g.fault ? "fault " : "done ");
  board_write(fw_fault_name(g.fault));
  const char* keys[] = {"code", "joint", "ticks", "state", "missed", "worst_work", "worst_link", "worst_control",
                        "worst_control_tick", "mean_control", "running_ticks", "frames_in", "frames_bad", "bytes_in",
                        "bytes_out", "frames_dropped", "stack"};
  long values[] = {g.fault, g.fault_joint, g.tick, g.state, g.missed, (long)g.work_max, (long)g.link_max,
                   (long)g.control_max, g.control_max_tick,
                   g.running_ticks ? (long)(g.control_sum / (uint64_t)g.running_ticks) : 0, g.running_ticks,
                   (long)g.frames_in,
                   (long)g.frames_bad, (long)g.bytes_in, (long)g.bytes_out, (long)g.frames_dropped,
                   (long)board_stack_used()};
  for (unsigned k = 0; k < sizeof values / sizeof values[0]; k++) {
    board_write(" ");
    board_write(keys[k]);
    board_write("=");
    board_write_int(values[k]);
  }
  board_write("\n");
}

int main(void) {
  board_stack_paint();
  char line[128] = {0};
  board_cmdline(line, sizeof line - 1);
  g.stop_after = arg_value(line, "ticks=", -1);
  g.once = arg_value(line, "once=", 0) != 0;
  g.clock_period_us = arg_value(line, "period_us=", 0);
  g.tolerance_us = arg_value(line, "tolerance_us=", 0);
  g.state = LINK_IDLE;
  g.fault_joint = -1;
  g.stop_ticks = g.silent_hold_ticks = -1;
  g.period_us = FW_DEFAULT_PERIOD_US;
  link_decoder_reset(&g.decoder);
  link_server_reset(&g.server);
  board_link_init();
  board_uart_init((uint32_t)arg_value(line, "baud=", 1000000));
  g.buses = (uint8_t)(1u << LINK_BUS_DYNAMIXEL);
  if (board_can_open((uint32_t)arg_value(line, "can_bitrate=", 1000000))) g.buses |= 1u << LINK_BUS_CAN;
  board_clock_start((uint32_t)((uint64_t)g.period_us * BOARD_CPU_HZ / 1000000u));
  g.scheduled = 0;
  while (g.stop_after < 0 || g.tick < g.stop_after) {
    board_tick_begin();
    uint32_t c0 = board_clock_now();
    int was_running = g.torque;
    g.flags = 0;
    int heavy = heavy_tick(), due = telemetry_due(heavy);
    if (!heavy && !(due && g.telemetry_every > 1)) poll_link();
    watchdog();
    uint32_t c1 = board_clock_now();
    if (g.torque) control_tick();
    uint32_t c2 = board_clock_now();
    telemetry(due);
    uint32_t c3 = board_clock_now();
    g.work = c3 - c0;
    if (was_running) {
      if (g.work > g.work_max) g.work_max = g.work;
      if ((c1 - c0) + (c3 - c2) > g.link_max) g.link_max = (c1 - c0) + (c3 - c2);
      if (c2 - c1 > g.control_max) g.control_max = c2 - c1, g.control_max_tick = g.tick;
      g.control_sum += c2 - c1;
      g.running_ticks++;
    }
    g.ran |= g.torque;
    g.tick++;
    if (g.once && g.ran && !g.torque) break;
    // the next period: at once when this tick ran past it (counted; a microcontroller faults)
    g.scheduled++;
    long behind = (long)(int32_t)(board_clock_ticks() - (uint32_t)g.scheduled);
    if (behind > 0) {              // a tick that set the bus up (HOME) may take longer: not a miss
      if (was_running) g.missed++;
      // a microcontroller's tick is deterministic: any overrun is a fault; a host OS may preempt the
      // loop, so there it may fall behind by up to the tolerance (tolerance_us=, fw_main.c's rule)
      long limit = FW_TOLERATE_OVERRUN ? g.tolerance_us / (long)g.period_us : 0;
      if (was_running && g.torque && behind > limit) fault(FW_FAULT_OVERRUN, -1);
      g.scheduled = (long)board_clock_ticks();
    } else if (behind < 0) {
      board_clock_wait();
    }
  }
  torque_off(g.fault ? LINK_FAULT : g.state);
  report();
  return g.fault;
}
