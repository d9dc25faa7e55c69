// can_double.c: a register-level test double of the STM32F405's bxCAN1, and the checks of the
// board's driver (firmware/boards/stm32f405/can.c) against it (tests/test_f405_can.py builds and
// runs this; exit status = failed checks). No QEMU machine models a CAN controller.
//
// The driver's registers are this file's memory. can_model_step() is the controller: the driver
// calls it in each of its bounded waits (F405_POLL), a check calls it as "bus time passes". It
// follows RM0090 32: MCR.INRQ -> MSR.INAK (unless the controller is dead), leaving initialisation
// only on an idle bus, TXRQ in a mailbox -> the frame on the bus (TME set again), the three-deep
// receive FIFO 0 behind the 32-bit mask-mode filter banks, FOVR when a fourth frame comes, RFOM
// releasing the output mailbox. RF0R is rc_w1/command bits on the chip and plain memory here:
// the model marks what it writes with a reserved bit (31), so a value without it was the driver's.
#include <stdio.h>
#include <string.h>

#include "can.h"
#include "stm32f405.h"

uint32_t g_can_regs[0x320 / 4];
uint32_t g_gpiob_regs[0x28 / 4];

#define R(offset) g_can_regs[(offset) / 4]
#define MODEL_MARK (1u << 31)

static struct {
  f405_can_frame fifo[3];
  int n;                       // frames in FIFO 0
  int overrun;                 // FOVR
  f405_can_frame sent[16];
  uint32_t sent_tir[16];       // the raw TIxR of each frame sent
  int nsent;
  int dead;                    // never acknowledges initialisation (no clock to the peripheral)
  int busy_bus;                // no 11 recessive bits: initialisation is never left
  int hold_tx;                 // the bus is taken: mailboxes stay pending
  long steps;
} m;

static void model_reset(void) {
  memset(g_can_regs, 0, sizeof g_can_regs);
  memset(g_gpiob_regs, 0, sizeof g_gpiob_regs);
  memset(&m, 0, sizeof m);
  R(0x000) = 0x00010002u;      // MCR reset value: SLEEP, DBF
  R(0x004) = 0x00000C02u;      // MSR: SLAK
  R(0x008) = 0x1C000000u;      // TSR: the three mailboxes empty
  R(0x00C) = MODEL_MARK;
}

static uint32_t word(const f405_can_frame* f) {
  return f->extended ? f->id << 3 | CAN_IR_IDE : f->id << 21;
}

static void show_fifo(void) {
  R(0x00C) = MODEL_MARK | (uint32_t)m.n | (m.n == 3 ? 1u << 3 : 0u) | (m.overrun ? CAN_RF0R_FOVR : 0u);
  if (m.n == 0) return;
  const f405_can_frame* f = &m.fifo[0];
  R(0x1B0) = word(f);
  R(0x1B4) = f->len;
  R(0x1B8) = (uint32_t)f->data[0] | (uint32_t)f->data[1] << 8 | (uint32_t)f->data[2] << 16 | (uint32_t)f->data[3] << 24;
  R(0x1BC) = (uint32_t)f->data[4] | (uint32_t)f->data[5] << 8 | (uint32_t)f->data[6] << 16 | (uint32_t)f->data[7] << 24;
}

// a frame from the bus: through the active 32-bit mask-mode banks into FIFO 0. 1 kept,
// 0 no filter took it, -1 lost to a full FIFO
static int deliver(const f405_can_frame* f) {
  if (R(0x200) & CAN_FMR_FINIT) return 0;          // filters in initialisation: nothing received
  int taken = 0;
  for (int bank = 0; bank < 14 && !taken; bank++) {
    uint32_t bit = 1u << bank;
    if (!(R(0x21C) & bit) || (R(0x204) & bit) || !(R(0x20C) & bit) || (R(0x214) & bit)) continue;
    taken = ((word(f) ^ R(0x240 + 8 * bank)) & R(0x244 + 8 * bank)) == 0;
  }
  if (!taken) return 0;
  if (m.n == 3) {
    m.overrun = 1;
    show_fifo();
    return -1;
  }
  m.fifo[m.n++] = *f;
  show_fifo();
  return 1;
}

void can_model_step(void) {
  m.steps++;
  uint32_t mcr = R(0x000), msr = R(0x004);
  if (!m.dead) {
    if (mcr & CAN_MCR_INRQ) msr = (msr | CAN_MSR_INAK) & ~CAN_MSR_SLAK;
    else if (mcr & CAN_MCR_SLEEP) msr = (msr | CAN_MSR_SLAK) & ~CAN_MSR_INAK;
    else if (!m.busy_bus) msr &= ~(CAN_MSR_INAK | CAN_MSR_SLAK);
    R(0x004) = msr;
  }
  int normal = !(msr & (CAN_MSR_INAK | CAN_MSR_SLAK));
  for (int k = 0; k < 3; k++) {
    uint32_t tir = R(0x180 + 0x10 * k);
    if (!(tir & CAN_TIR_TXRQ)) continue;
    if (!normal || m.hold_tx) {
      R(0x008) &= ~CAN_TSR_TME(k);
      continue;
    }
    f405_can_frame f = {0};
    f.extended = (tir & CAN_IR_IDE) != 0;
    f.id = f.extended ? tir >> 3 : tir >> 21;
    f.len = (uint8_t)(R(0x184 + 0x10 * k) & 0xF);
    uint32_t lo = R(0x188 + 0x10 * k), hi = R(0x18C + 0x10 * k);
    for (int b = 0; b < 4; b++) f.data[b] = (uint8_t)(lo >> 8 * b), f.data[4 + b] = (uint8_t)(hi >> 8 * b);
    m.sent_tir[m.nsent] = tir;
    m.sent[m.nsent++] = f;
    R(0x180 + 0x10 * k) = tir & ~CAN_TIR_TXRQ;
    R(0x008) |= CAN_TSR_TME(k);
    if (R(0x01C) & CAN_BTR_LBKM) deliver(&f);     // loopback: the controller hears itself
  }
  uint32_t rf = R(0x00C);
  if (!(rf & MODEL_MARK)) {                        // the driver wrote RF0R
    if (rf & CAN_RF0R_FOVR) m.overrun = 0;
    if ((rf & CAN_RF0R_RFOM) && m.n > 0) {
      memmove(&m.fifo[0], &m.fifo[1], sizeof m.fifo[0] * 2);
      m.n--;
    }
  }
  show_fifo();
}

//---------------------------------- the checks ---------------------------------------------------

static int g_checks, g_failed;

#define CHECK(cond, why)                                                              \
  do {                                                                                \
    g_checks++;                                                                       \
    if (!(cond)) {                                                                    \
      g_failed++;                                                                     \
      printf("FAIL %s:%d: %s (%s)\n", __FILE__, __LINE__, #cond, why);                \
    }                                                                                 \
  } while (0)

static f405_can_frame frame(uint32_t id, int extended, int len, uint8_t first) {
  f405_can_frame f = {.id = id, .extended = (uint8_t)extended, .len = (uint8_t)len};
  for (int k = 0; k < 8; k++) f.data[k] = (uint8_t)(first + k);
  return f;
}

static int same(const f405_can_frame* a, const f405_can_frame* b) {
  return a->id == b->id && a->extended == b->extended && a->len == b->len && !memcmp(a->data, b->data, a->len);
}

int main(void) {
  // bit timing: 42 MHz / (prescaler x 14 tq); BTR = BRP-1 | (TS1-1)<<16 | (TS2-1)<<20, SJW-1 = 0
  CHECK(f405_can_timing(1000000) == 0x001A0002u, "1 Mbit/s: prescaler 3 (42 MHz / 3 / 14 = 1 MHz)");
  CHECK(f405_can_timing(500000) == 0x001A0005u, "500 kbit/s: prescaler 6");
  CHECK(f405_can_timing(125000) == 0x001A0017u, "125 kbit/s: prescaler 24");
  CHECK(f405_can_timing(400000) == 0, "400 kbit/s: 42 MHz / 5.6 MHz = 7.5, no exact prescaler");

  model_reset();
  CHECK(f405_can_init(400000, 0) == F405_CAN_BITRATE, "a rate with no exact timing is refused");
  CHECK(R(0x000) == 0x00010002u, "refused before any register is touched");

  model_reset();
  CHECK(f405_can_init(1000000, 0) == F405_CAN_OK, "init from reset (sleep)");
  CHECK(R(0x01C) == 0x001A0002u, "BTR written in initialisation mode");
  CHECK(R(0x000) == (CAN_MCR_ABOM | CAN_MCR_TXFP), "MCR: automatic bus-off recovery, FIFO transmit order, awake, normal");
  CHECK((R(0x004) & (CAN_MSR_INAK | CAN_MSR_SLAK)) == 0, "the controller left initialisation and sleep");
  CHECK(((g_gpiob_regs[0] >> 16) & 0xFu) == 0xAu, "PB8, PB9 in alternate-function mode (MODER 10 10)");
  CHECK((g_gpiob_regs[0x24 / 4] & 0xFFu) == 0x99u, "PB8, PB9 on AF9 (CAN1)");

  model_reset();
  m.dead = 1;
  CHECK(f405_can_init(1000000, 0) == F405_CAN_TIMEOUT, "no acknowledge of INRQ: a timeout, not a hang");
  CHECK(m.steps == 100000, "the wait is bounded: 100,000 polls");
  model_reset();
  m.busy_bus = 1;
  CHECK(f405_can_init(1000000, 0) == F405_CAN_TIMEOUT, "a bus never idle: initialisation not left, a timeout");

  // transmit
  model_reset();
  f405_can_init(1000000, 0);
  f405_can_frame a = frame(0x141, 0, 8, 0x10), b = frame(0x1ABCDEF, 1, 3, 0x20), got;
  CHECK(f405_can_send(&a) == F405_CAN_OK, "a standard frame queued");
  can_model_step();
  CHECK(m.nsent == 1 && same(&m.sent[0], &a), "the standard frame on the bus as given");
  CHECK(m.sent_tir[0] == (0x141u << 21 | CAN_TIR_TXRQ), "TI0R: STID at bits 31..21, TXRQ");
  CHECK(f405_can_send(&b) == F405_CAN_OK, "an extended frame queued");
  can_model_step();
  CHECK(m.nsent == 2 && same(&m.sent[1], &b), "the extended frame on the bus as given (3 bytes)");
  CHECK(m.sent_tir[1] == (0x1ABCDEFu << 3 | CAN_IR_IDE | CAN_TIR_TXRQ), "TIxR: EXID at bits 31..3, IDE");
  f405_can_frame bad = frame(0x800, 0, 8, 0);
  CHECK(f405_can_send(&bad) == F405_CAN_ARGUMENT, "an 11-bit identifier of 0x800 is refused");
  bad = frame(0x10, 0, 9, 0);
  CHECK(f405_can_send(&bad) == F405_CAN_ARGUMENT, "9 data bytes are refused");

  m.hold_tx = 1;                   // the bus is busy: mailboxes fill
  for (int k = 0; k < 3; k++) {
    f405_can_frame f = frame(0x200u + (uint32_t)k, 0, 2, (uint8_t)k);
    CHECK(f405_can_send(&f) == F405_CAN_OK, "three mailboxes");
    can_model_step();
  }
  f405_can_frame fourth = frame(0x203, 0, 1, 9);
  CHECK(f405_can_send(&fourth) == F405_CAN_FULL, "a fourth frame with three pending: full, not lost silently");
  m.hold_tx = 0;
  can_model_step();
  CHECK(m.nsent == 5 && m.sent[2].id == 0x200 && m.sent[4].id == 0x202, "the three in the order queued (TXFP)");
  CHECK(f405_can_send(&fourth) == F405_CAN_OK, "a mailbox free again");

  // receive through a filter
  CHECK(f405_can_filter(14, 0, 0, 0) == F405_CAN_ARGUMENT, "bank 14 is CAN2's");
  CHECK(f405_can_filter(0, 0x100, 0x700, 0) == F405_CAN_OK, "bank 0: standard 0x100..0x1FF");
  CHECK(f405_can_receive(&got) == 0, "nothing received yet");
  f405_can_frame in = frame(0x141, 0, 8, 0x40), other = frame(0x241, 0, 8, 0), ext = frame(0x141, 1, 8, 0);
  CHECK(deliver(&in) == 1, "0x141 passes the filter");
  CHECK(deliver(&other) == 0, "0x241 does not (0x241 & 0x700 != 0x100)");
  CHECK(deliver(&ext) == 0, "an extended 0x141 does not (IDE is matched)");
  CHECK(f405_can_receive(&got) == 1 && same(&got, &in), "0x141 read back as sent");
  can_model_step();
  CHECK(f405_can_receive(&got) == 0, "FIFO empty after the release");

  // overrun: four frames, three mailboxes
  CHECK(f405_can_filter(1, 0, 0, 1) == F405_CAN_OK, "bank 1: every extended frame");
  for (int k = 0; k < 4; k++) {
    f405_can_frame f = frame(0x10000u + (uint32_t)k, 1, 4, (uint8_t)(16 * k));
    deliver(&f);
  }
  for (int k = 0; k < 3; k++) {
    CHECK(f405_can_receive(&got) == 1 && got.id == 0x10000u + (uint32_t)k && got.data[0] == 16 * k,
          "the three kept, oldest first");
    can_model_step();
  }
  CHECK(f405_can_receive(&got) == 0, "the fourth was lost");
  CHECK(f405_can_overruns() == 1, "and counted once");
  can_model_step();
  CHECK(!m.overrun, "FOVR cleared by the driver's write");

  // loopback: a bench test without a bus
  model_reset();
  CHECK(f405_can_init(500000, 1) == F405_CAN_OK && (R(0x01C) & CAN_BTR_LBKM), "loopback mode");
  f405_can_filter(0, 0, 0, 0);
  f405_can_frame echo = frame(0x7FF, 0, 0, 0);
  f405_can_send(&echo);
  can_model_step();
  CHECK(f405_can_receive(&got) == 1 && same(&got, &echo), "a frame sent in loopback is received (0 bytes, id 0x7FF)");

  printf("f405 can: %d checks, %d failed\n", g_checks, g_failed);
  return g_failed;
}
