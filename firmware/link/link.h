// link.h: the host link, the protocol between the host (servodyn on a PC) and the controller
// (the firmware): framing, the controller's side of the retransmit rule, every message's pack and
// unpack, and the assembly of a robot loaded over the link with the core's own checks.
//
// docs/host-link.md is the protocol with every message's bytes; the Python side is servodyn.hal.link
// (hal/link/), which agrees byte for byte (tests/test_host_link.py). No heap, no stdio: builders
// write into the caller's buffer, the decoder takes one byte at a time in constant work (an ISR can
// feed it). Built with sd_real = double (host, tests) and float (-DSD_SINGLE, the firmware); the
// wire is the same in both: float32 and fixed-point fields, little-endian.
//
// A frame on the wire is COBS(raw) 00, raw being
//   VER SEQ ACK TYPE LEN_L LEN_H | payload (LEN bytes) | CRC_H CRC_L
// VER = LINK_VERSION, SEQ the sender's sequence number, ACK the next SEQ the sender expects from
// its peer, CRC the Dynamixel CRC-16 (poly 0x8005, init 0, hal/dynamixel/c/dxl.h's dxl_crc) of
// VER..payload, high byte first so that the CRC of the whole raw frame is 0.
#ifndef LINK_H
#define LINK_H

#include <stddef.h>
#include <stdint.h>

#include "servodyn.h"

#define LINK_VERSION 1
#define LINK_FW_MAJOR 0
#define LINK_FW_MINOR 1
#define LINK_FW_PATCH 0

enum {
  LINK_HEADER = 6,                                   // VER SEQ ACK TYPE LEN(2)
  LINK_CRC = 2,
  LINK_MAX_PAYLOAD = 240,                            // so a raw frame fits one COBS block
  LINK_MAX_RAW = LINK_HEADER + LINK_MAX_PAYLOAD + LINK_CRC,   // 248
  LINK_MAX_WIRE = LINK_MAX_RAW + 2,                  // + the COBS code byte + the 00 delimiter
  LINK_WINDOW = 8,                                   // requests in flight; results the controller keeps
  LINK_BOARD_NAME = 12,
  LINK_MAX_TELEMETRY_JOINT = 16,                     // joints in one telemetry frame
};

// message types: requests (host -> controller, reliable) below 0x80, the controller's above
enum link_type_ {
  LINK_HELLO = 0x01,
  LINK_LOAD_ROBOT = 0x02,
  LINK_LOAD_BODY = 0x03,
  LINK_LOAD_JOINT = 0x04,
  LINK_COMMIT = 0x05,
  LINK_KNOTS = 0x06,
  LINK_COMMAND = 0x07,
  LINK_HELLO_REPLY = 0x81,
  LINK_RESULT = 0x82,
  LINK_TELEMETRY = 0x83,
};

//---------------------------------- framing ------------------------------------------------------

// One frame, COBS-encoded and ended by 00, into out; returns its length, or 0 when the payload is
// over LINK_MAX_PAYLOAD or the frame does not fit cap (at most LINK_MAX_WIRE).
size_t link_frame(uint8_t* out, size_t cap, uint8_t seq, uint8_t ack, uint8_t type,
                  const uint8_t* payload, size_t n);

enum link_feed_ {
  LINK_MORE = 0,             // nothing complete yet (an empty frame, 00 00, is nothing)
  LINK_FRAME = 1,            // a good frame: version, seq, ack, type, len and payload hold it
  LINK_BAD_CRC = -1,         // a frame whose CRC does not match
  LINK_BAD_SHORT = -2,       // under the header and CRC, or its last COBS block cut short
  LINK_BAD_LENGTH = -3,      // LEN disagrees with the bytes received
  LINK_BAD_TOO_LONG = -4,    // more than LINK_MAX_RAW bytes before the delimiter
  LINK_BAD_VERSION = -5,     // a good frame of another version (version, seq, type hold it)
};

// The streaming decoder: feed the received bytes one at a time. A lost or corrupt byte costs the
// frame it falls in (and the next one, when it is the delimiter), never more: every 00 ends a frame.
typedef struct link_decoder_ {
  uint16_t n;                     // raw bytes decoded so far
  uint16_t crc;                   // CRC of them
  uint8_t block;                  // data bytes left in the current COBS block
  uint8_t code;                   // the current block's code byte (0: none yet)
  uint8_t dropping;               // 1: too long, waiting for the delimiter
  uint8_t version, seq, ack, type;
  uint16_t len;
  const uint8_t* payload;         // into raw, valid until the next byte is fed
  uint8_t raw[LINK_MAX_RAW];
} link_decoder;

void link_decoder_reset(link_decoder* d);
int link_decoder_feed(link_decoder* d, uint8_t byte);
// The same on n bytes: feeds them until a verdict other than LINK_MORE, which it returns, and *used
// the bytes taken (all n with LINK_MORE). The bytes inside a COBS block go in one tight loop.
int link_decoder_feed_bytes(link_decoder* d, const uint8_t* data, size_t n, size_t* used);

//---------------------------------- result codes -------------------------------------------------
// A RESULT names the stage that refused a request and that stage's own code: the link's below,
// or the core's checks (sd_model_setup, sd_control_check, sd_observer_check), or the servo map's.

enum link_stage_ {
  LINK_STAGE_LINK = 0,
  LINK_STAGE_MODEL = 1,      // code: sd_model_setup's (servodyn.h), index: the body
  LINK_STAGE_CONTROL = 2,    // code: sd_control_check's (sd_control.h)
  LINK_STAGE_OBSERVER = 3,   // code: sd_observer_check's (sd_observer.h)
  LINK_STAGE_SERVO = 4,      // code: link_servo_error_, index: the joint (-1: the robot's table)
};

enum link_error_ {
  LINK_OK = 0,
  LINK_E_TYPE = -1,          // an unknown request type
  LINK_E_PAYLOAD = -2,       // a payload of the wrong length for its type or its counts
  LINK_E_STATE = -3,         // not now: e.g. a body before LOAD_ROBOT, PLAY without a robot
  LINK_E_FULL = -4,          // more knots than the free slots
  LINK_E_ORDER = -5,         // not the SEQ expected (the frame's ACK says which): dropped
  LINK_E_SIZE = -6,          // over the compiled sizes (bodies, dofs, knots)
  LINK_E_INCOMPLETE = -7,    // COMMIT before every body came (index: the first missing body)
  LINK_E_KNOT = -8,          // a knot not next in the motion, or its time not after the last one's
  LINK_E_COMMAND = -9,       // an unknown command
  LINK_E_NO_JOINT = -10,     // COMMIT before every joint came (index: the first missing joint)
  LINK_E_VERSION = -11,      // a frame of another version (the reply's VER is the controller's)
};

enum link_servo_error_ {
  LINK_SERVO_BUS = -1,       // a bus the controller has not, or none for an actuated dof
  LINK_SERVO_DIRECTION = -2, // direction not +1 or -1
  LINK_SERVO_SCALE = -3,     // a unit scale (gear, position, speed, effort) zero or not finite
  LINK_SERVO_RANGE = -4,     // q_min >= q_max, a speed or effort limit not positive, not finite
  LINK_SERVO_SAFETY = -5,    // a following error or contact threshold not positive; a bad table
  LINK_SERVO_DUPLICATE = -6, // two joints on one servo (bus and id)
  LINK_SERVO_CAN = -7,       // a CAN motor's dialect, reply id or MIT ranges (hal/can/c/canmotor.h's)
};

//---------------------------------- messages -----------------------------------------------------
// Each message has a struct, link_pack_NAME (payload bytes into p, returns their count, 0 when
// cap is too small) and link_unpack_NAME (LINK_OK or LINK_E_PAYLOAD for a wrong length). Reals are
// float32 on the wire whatever sd_real is; telemetry's are fixed-point (below).

typedef struct link_hello_ {
  uint16_t nonce;                 // echoed by the reply: which hello it answers
} link_hello;

enum link_bus_ { LINK_BUS_NONE = 0, LINK_BUS_DYNAMIXEL = 1, LINK_BUS_CAN = 2 };
// a CAN motor's dialect (hal/can/dialects.py): how it answers, where, and what its status means
enum link_dialect_ { LINK_DIALECT_NONE = 0, LINK_DIALECT_MIT = 1, LINK_DIALECT_DAMIAO = 2, LINK_DIALECT_CUBEMARS = 3,
                     LINK_NDIALECT };
enum link_state_ { LINK_IDLE = 0, LINK_LOADED = 1, LINK_HOMING = 2, LINK_PLAYING = 3, LINK_HOLDING = 4,
                   LINK_TORQUE_OFF = 5, LINK_FAULT = 6 };

typedef struct link_hello_reply_ {
  uint16_t nonce;
  uint8_t link_version;
  uint8_t fw_major, fw_minor, fw_patch;
  char board[LINK_BOARD_NAME];    // NUL-padded
  uint8_t real_bytes;             // sizeof(sd_real): 4 float, 8 double
  uint8_t max_body, max_dof;      // the compiled sizes
  uint16_t knot_slots;            // the knot buffer
  uint8_t max_payload, window;
  uint8_t buses;                  // bit (1 << link_bus_) per bus the controller drives
  uint8_t state;                  // a link_state_
} link_hello_reply;

enum link_reaction_ { LINK_REACT_HOLD = 0, LINK_REACT_FLOAT = 1, LINK_REACT_RETRACT = 2,
                      LINK_REACT_TORQUE_OFF = 3, LINK_NREACTION };

// LOAD_ROBOT: the robot's sizes, controller and safety table (hal/safety.py); starts a load
typedef struct link_robot_head_ {
  uint8_t nbody, ndof, free_root;
  uint8_t mode;                   // an sd_control_mode_
  uint8_t contact;                // 1: the observer watches for contact
  uint8_t contact_debounce;       // ticks in a row over a threshold that are a contact
  uint8_t reaction;               // a link_reaction_
  uint16_t update_ticks;          // control periods per inverse dynamics
  uint16_t host_timeout_ms;       // host silent this long: hold; reaction_time later torque off
  uint32_t period_us;             // the control period
  sd_real gravity[3];             // m/s^2, base frame
  sd_real friction_speed;         // rad/s
  sd_real stall_time, stall_speed, stall_share;   // s, rad/s, share of the torque limit
  sd_real contact_arm_time;       // s after the observer starts before a contact counts
  sd_real reaction_time;          // s the reaction runs before torque goes off
} link_robot_head;

// LOAD_BODY: one body of the model (servodyn.h's fields)
typedef struct link_body_ {
  uint8_t index;
  int8_t parent;
  uint8_t dofnum, ball;
  sd_real pos[3], rot[9], mass, com[3], inertia[6];
} link_body;

// LOAD_JOINT: one dof: its frame and armature, its servo and units (fw_app.h's fw_servo), its
// limits, friction, gains and safety values. A CAN motor's units are its MIT ranges (mit_range;
// rad_per_tick, radps_per_unit and effort_per_unit 0), its effort A (effort_limit, nm_per_effort:
// the stall guard's torque limit); id its command id, reply_id the id it answers on.
typedef struct link_joint_ {
  uint8_t index, bus, id;
  uint16_t model_number;
  sd_real dof_rot[9], armature;
  sd_real direction, zero_offset, gear_ratio;   // horn = direction * gear_ratio * q + zero_offset
  sd_real rad_per_tick, radps_per_unit;         // horn rad per position unit, rad/s per speed unit
  sd_real effort_per_unit;                      // A (or duty) per command unit
  sd_real nm_per_effort;                        // joint N m per A (or per duty)
  sd_real effort_limit;                         // A (or duty): commands clamped here
  sd_real q_min, q_max, qd_max, tau_max;
  sd_real friction_coulomb, friction_viscous;
  sd_real kp, kd, error_lowpass;
  sd_real following_error;                      // rad
  sd_real observer_gain, observer_lowpass, contact_threshold;   // 1/s, rad/s, N m
  uint8_t dialect;                              // CAN: a link_dialect_; Dynamixel: LINK_DIALECT_NONE
  uint16_t reply_id;                            // CAN: the id its answers come on (11 bits)
  sd_real mit_range[5];                         // CAN: p_max, v_max, t_max, kp_max, kd_max (cm_ranges)
} link_joint;

// KNOTS: a stretch of the motion, knots first .. first + count - 1, each a time and the state the
// host computed (so each segment is the quintic through its two knots, as sd_trajectory_eval)
enum link_knot_flag_ { LINK_KNOT_GAINS = 1, LINK_KNOT_LAST = 2 };

typedef struct link_knots_ {
  uint32_t first;
  uint8_t ndof, count, flags;
} link_knots;

typedef struct link_knot_ {
  uint32_t t_us;                  // µs from the motion's start
  sd_real q[SD_MAX_DOF], qd[SD_MAX_DOF], qdd[SD_MAX_DOF];
  sd_real kp[SD_MAX_DOF], kd[SD_MAX_DOF];       // with LINK_KNOT_GAINS: the gains there (linear between)
} link_knot;

enum link_command_code_ {
  LINK_CMD_KEEPALIVE = 0,         // nothing: resets the host watchdog
  LINK_CMD_HOME = 1,              // arg: ms of the minimum-jerk move to the motion's first knot
  LINK_CMD_PLAY = 2,              // play the streamed motion from its first knot
  LINK_CMD_HOLD = 3,              // hold the present desired pose
  LINK_CMD_STOP = 4,              // end the run: the safety table's reaction, then torque off
  LINK_CMD_TORQUE_OFF = 5,        // torque off at once
  LINK_CMD_CLEAR_FAULT = 6,       // forget the fault, back to LOADED (torque off)
  LINK_CMD_TELEMETRY = 7,         // arg: telemetry every arg ticks (0: none)
  LINK_NCOMMAND
};

typedef struct link_command_ {
  uint8_t command;
  uint32_t arg;
} link_command;

typedef struct link_result_ {
  uint8_t seq, type;              // the request answered
  uint8_t stage;                  // a link_stage_
  int8_t code;                    // 0: done; else that stage's code
  int16_t index;                  // the body, joint or knot named, or -1
  uint16_t credits;               // free knot slots after this request
} link_result;

// Telemetry: fixed-point int16, value = code * LSB, code -32768 = not a number (or not measured),
// codes clamped to +-32767 (then LINK_TM_SATURATED is set). command and effort are the servo's
// own integer units, exact.
#define LINK_LSB_Q      (SD_R(1.0) / SD_R(4096.0))   // rad: +-8 rad
#define LINK_LSB_QD     (SD_R(1.0) / SD_R(512.0))    // rad/s: +-64 rad/s
#define LINK_LSB_TAU    (SD_R(1.0) / SD_R(512.0))    // N m: +-64 N m (torque and residual)
#define LINK_NAN_CODE   (-32768)

enum link_tm_flag_ { LINK_TM_LIMITED = 1, LINK_TM_SATURATED = 2, LINK_TM_CONTACT = 4,
                     LINK_TM_STARVED = 8, LINK_TM_DONE = 16, LINK_TM_HOST_SILENT = 32 };

typedef struct link_joint_tm_ {
  sd_real q, qd, q_d, tau;        // measured position, speed; desired position; commanded torque
  int16_t effort, command;        // measured current (or duty), sent command: servo units
  sd_real residual;               // the momentum observer's, N m
} link_joint_tm;

typedef struct link_telemetry_ {
  uint32_t tick;                  // control periods since the controller started
  uint16_t work_us;               // the tick's work, µs
  uint16_t missed;                // deadlines missed so far (saturates)
  uint8_t state, fault, fault_joint, flags;
  uint16_t credits;               // free knot slots
  uint8_t njoint;
  link_joint_tm joint[LINK_MAX_TELEMETRY_JOINT];
} link_telemetry;

size_t link_pack_hello(uint8_t* p, size_t cap, const link_hello* m);
int link_unpack_hello(const uint8_t* p, size_t n, link_hello* m);
size_t link_pack_hello_reply(uint8_t* p, size_t cap, const link_hello_reply* m);
int link_unpack_hello_reply(const uint8_t* p, size_t n, link_hello_reply* m);
size_t link_pack_robot_head(uint8_t* p, size_t cap, const link_robot_head* m);
int link_unpack_robot_head(const uint8_t* p, size_t n, link_robot_head* m);
size_t link_pack_body(uint8_t* p, size_t cap, const link_body* m);
int link_unpack_body(const uint8_t* p, size_t n, link_body* m);
size_t link_pack_joint(uint8_t* p, size_t cap, const link_joint* m);
int link_unpack_joint(const uint8_t* p, size_t n, link_joint* m);
size_t link_pack_command(uint8_t* p, size_t cap, const link_command* m);
int link_unpack_command(const uint8_t* p, size_t n, link_command* m);
size_t link_pack_result(uint8_t* p, size_t cap, const link_result* m);
int link_unpack_result(const uint8_t* p, size_t n, link_result* m);
// the flags written are m->flags, with LINK_TM_SATURATED added when a value was clamped
size_t link_pack_telemetry(uint8_t* p, size_t cap, const link_telemetry* m);
int link_unpack_telemetry(const uint8_t* p, size_t n, link_telemetry* m);
// knots: the header and count knots (each of ndof dofs, gains with LINK_KNOT_GAINS)
size_t link_knot_bytes(int ndof, int flags);  // one knot's bytes on the wire
size_t link_pack_knots(uint8_t* p, size_t cap, const link_knots* m, const link_knot* knots);
// checks the header and the length; then link_knot_at reads knot k (0..count-1) of that payload
int link_unpack_knots(const uint8_t* p, size_t n, link_knots* m);
void link_knot_at(const uint8_t* p, const link_knots* m, int k, link_knot* out);

//---------------------------------- the controller's side of the retransmit rule -----------------
// The controller expects SEQ E. A request with SEQ E is executed (LINK_EXECUTE; the caller then
// gives its result to link_server_done, which keeps it and moves E on). One with SEQ in
// E - LINK_WINDOW .. E - 1 was executed already and its result was lost: LINK_REPEAT, *reply is
// the result kept, sent again and nothing executed. Any other SEQ is dropped: LINK_REFUSE, *reply
// is LINK_E_ORDER (a NAK; the frame's ACK, E, tells the host where to go back to). HELLO starts a
// session at any SEQ: E = its SEQ, results forgotten. Before the first HELLO every request is refused.
enum link_accept_ { LINK_EXECUTE = 1, LINK_REPEAT = 2, LINK_REFUSE = 3 };

typedef struct link_server_ {
  uint8_t expected;               // E: the ACK of every frame the controller sends
  uint8_t started;                // a HELLO came
  uint8_t kept[LINK_WINDOW];      // 1: result[seq % LINK_WINDOW] holds that seq's result
  link_result result[LINK_WINDOW];
} link_server;

void link_server_reset(link_server* s);
int link_server_accept(link_server* s, uint8_t seq, uint8_t type, link_result* reply);
void link_server_done(link_server* s, const link_result* result);

//---------------------------------- the knot buffer ----------------------------------------------
// KNOTS go into a ring of `slots` knots (at most SD_MAX_KNOT): a KNOTS message is taken whole or
// refused, LINK_E_FULL when its knots are more than the free slots, LINK_E_KNOT when its first is
// not the next index of the motion (index: the index expected) or a time is not after the one
// before it (index: that knot), LINK_E_PAYLOAD for another ndof or a wrong length, LINK_E_STATE
// after the motion's last knot. result->credits is then the free slots (every RESULT and telemetry
// frame reports them: the host's flow control). The playing loop reads the oldest knots and pops
// each once it is behind the clock.

typedef struct link_ring_ {
  uint16_t slots, head, count;    // capacity, the oldest knot's slot, knots held
  uint32_t next;                  // the index the next knot must have
  uint32_t last_t_us;             // the last knot's time
  uint8_t ndof, ended;            // ended: the motion's last knot came
  link_knot knot[SD_MAX_KNOT];
} link_ring;

void link_ring_reset(link_ring* r, int ndof, int slots);
void link_ring_push(link_ring* r, const uint8_t* payload, size_t n, link_result* result);
uint16_t link_ring_free(const link_ring* r);
const link_knot* link_ring_at(const link_ring* r, int k);   // k-th oldest held, NULL past count
void link_ring_pop(link_ring* r);                           // the oldest goes

//---------------------------------- a robot loaded over the link ---------------------------------
// LOAD_ROBOT starts a load (link_robot_begin), LOAD_BODY and LOAD_JOINT fill it, COMMIT checks it
// (link_robot_commit) with the core's checks: sd_model_setup, then every joint's servo map and
// safety values, then sd_control_check and sd_observer_check. A refusal's result names the stage,
// its code and the body or joint; an accepted robot has model, control and observer set up.

typedef struct link_robot_ {
  link_robot_head head;
  uint8_t begun, ready;
  uint8_t body_seen[SD_MAX_BODY];
  uint8_t joint_seen[SD_MAX_DOF];
  link_joint joint[SD_MAX_DOF];
  sd_model model;
  sd_control_config control;
  sd_observer_config observer;
} link_robot;

// each fills result's stage, code and index (seq, type and credits are the caller's)
void link_robot_begin(link_robot* r, const link_robot_head* head, link_result* result);
void link_robot_body(link_robot* r, const link_body* body, link_result* result);
void link_robot_joint(link_robot* r, const link_joint* joint, link_result* result);
// buses: the controller's (link_hello_reply.buses)
void link_robot_commit(link_robot* r, uint8_t buses, link_result* result);

#ifdef LINK_TEXT
//---------------------------------- host-side helpers --------------------------------------------
// Built into host tools and tests only (-DLINK_TEXT: stdio); opaque objects for a foreign-function
// caller (tests/test_host_link.py through ctypes), the messages as bytes.

// Unpack a payload of a type, write its fields as text ("name=value ...", arrays comma-separated,
// reals %.17g, in layout order) and pack it again into out (*on bytes). LINK_OK or the unpack's error.
int link_host_recode(uint8_t type, const uint8_t* p, size_t n, char* text, size_t tcap, uint8_t* out,
                     size_t ocap, size_t* on);
size_t link_host_sizeof(int what);   // 0 link_decoder, 1 link_server, 2 link_robot, 3 link_ring
// link_ring_push with its result packed as a RESULT payload (seq 0); returns the credits
uint16_t link_host_ring_push(link_ring* r, const uint8_t* p, size_t n, uint8_t result[8]);
// feed until a verdict: *used bytes taken, head = VER SEQ ACK TYPE, a good frame's payload copied
int link_host_feed(link_decoder* d, const uint8_t* data, size_t n, size_t* used, uint8_t head[4],
                   uint8_t* payload, uint16_t* len);
// link_server_accept with the reply (REPEAT, REFUSE) packed as a RESULT payload
int link_host_accept(link_server* s, uint8_t seq, uint8_t type, uint8_t reply[8]);
void link_host_done(link_server* s, const uint8_t* result, size_t n);   // a RESULT payload
uint8_t link_host_expected(const link_server* s);
// a LOAD_ROBOT, LOAD_BODY, LOAD_JOINT or COMMIT payload applied to r; its RESULT payload, the code returned
int link_host_robot(link_robot* r, uint8_t type, const uint8_t* p, size_t n, uint8_t buses,
                    uint8_t result[8]);
#endif

#endif  // LINK_H
