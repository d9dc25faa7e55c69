// can.c: bxCAN1 (RM0090 32): initialisation, one filter bank a call, frames in and out, polled.
// See can.h. Registers are the chip's (stm32f405.h); every wait is bounded, with F405_POLL() in
// its body (the host test double steps its device model there).
#include "can.h"

#include "stm32f405.h"

#define CAN_POLLS 100000u
#define APB1_HZ 42000000u
#define TQ_PER_BIT 14u
#define TS1 11u
#define TS2 2u
#define CAN_FILTER_BANKS 14

static uint32_t g_overruns;

static int wait_msr(uint32_t mask, uint32_t want) {
  for (uint32_t n = 0; n < CAN_POLLS; n++) {
    if ((CAN_MSR & mask) == want) return 1;
    F405_POLL();
  }
  return 0;
}

uint32_t f405_can_timing(uint32_t bitrate) {
  if (bitrate == 0 || APB1_HZ % (TQ_PER_BIT * bitrate) != 0) return 0;
  uint32_t prescaler = APB1_HZ / (TQ_PER_BIT * bitrate);
  if (prescaler > 1024u) return 0;
  return (prescaler - 1u) | (TS1 - 1u) << 16 | (TS2 - 1u) << 20 | 0u << 24;   // SJW = 1 tq
}

int f405_can_init(uint32_t bitrate, int loopback) {
  uint32_t btr = f405_can_timing(bitrate);
  if (!btr) return F405_CAN_BITRATE;
  // GPIOB 8, 9 to alternate function 9 (CAN1); their clocks are on (clock.c)
  GPIO_MODER(GPIOB_BASE) = (GPIO_MODER(GPIOB_BASE) & ~(0xFu << 16)) | (GPIO_MODE_AF * 5u) << 16;
  GPIO_AFRH(GPIOB_BASE) = (GPIO_AFRH(GPIOB_BASE) & ~0xFFu) | 0x99u;
  CAN_MCR = (CAN_MCR & ~CAN_MCR_SLEEP) | CAN_MCR_INRQ;
  if (!wait_msr(CAN_MSR_INAK | CAN_MSR_SLAK, CAN_MSR_INAK)) return F405_CAN_TIMEOUT;
  CAN_MCR = CAN_MCR_INRQ | CAN_MCR_ABOM | CAN_MCR_TXFP;
  CAN_BTR = btr | (loopback ? CAN_BTR_LBKM : 0u);
  g_overruns = 0;
  CAN_MCR &= ~CAN_MCR_INRQ;
  if (!wait_msr(CAN_MSR_INAK, 0)) return F405_CAN_TIMEOUT;
  return F405_CAN_OK;
}

// a 32-bit filter register: STID[10:0] at 31..21, or EXID[28:0] at 31..3 with IDE (bit 2)
static uint32_t filter_word(uint32_t id, int extended) {
  return extended ? (id & 0x1FFFFFFFu) << 3 | CAN_IR_IDE : (id & 0x7FFu) << 21;
}

int f405_can_filter(int bank, uint32_t id, uint32_t mask, int extended) {
  if (bank < 0 || bank >= CAN_FILTER_BANKS) return F405_CAN_ARGUMENT;
  uint32_t bit = 1u << bank;
  CAN_FMR |= CAN_FMR_FINIT;
  CAN_FA1R &= ~bit;
  CAN_FM1R &= ~bit;                    // mask mode
  CAN_FS1R |= bit;                     // one 32-bit filter
  CAN_FFA1R &= ~bit;                   // into FIFO 0
  CAN_FR1(bank) = filter_word(id, extended);
  CAN_FR2(bank) = filter_word(mask, extended) | CAN_IR_IDE;   // the kind must match too
  CAN_FA1R |= bit;
  CAN_FMR &= ~CAN_FMR_FINIT;
  return F405_CAN_OK;
}

int f405_can_send(const f405_can_frame* frame) {
  if (frame->len > 8 || frame->id > (frame->extended ? 0x1FFFFFFFu : 0x7FFu)) return F405_CAN_ARGUMENT;
  uint32_t tsr = CAN_TSR;
  int m = tsr & CAN_TSR_TME(0) ? 0 : tsr & CAN_TSR_TME(1) ? 1 : tsr & CAN_TSR_TME(2) ? 2 : -1;
  if (m < 0) return F405_CAN_FULL;
  const uint8_t* d = frame->data;
  CAN_TDTR(m) = frame->len;
  CAN_TDLR(m) = (uint32_t)d[0] | (uint32_t)d[1] << 8 | (uint32_t)d[2] << 16 | (uint32_t)d[3] << 24;
  CAN_TDHR(m) = (uint32_t)d[4] | (uint32_t)d[5] << 8 | (uint32_t)d[6] << 16 | (uint32_t)d[7] << 24;
  CAN_TIR(m) = filter_word(frame->id, frame->extended) | CAN_TIR_TXRQ;
  return F405_CAN_OK;
}

int f405_can_receive(f405_can_frame* frame) {
  uint32_t rf = CAN_RF0R;
  uint32_t overrun = rf & CAN_RF0R_FOVR;   // a frame arrived to a full FIFO and was lost
  if (overrun) g_overruns++;
  if (!(rf & CAN_RF0R_FMP_MASK)) {
    if (overrun) CAN_RF0R = CAN_RF0R_FOVR;   // write 1 to clear
    return 0;
  }
  uint32_t ir = CAN_RI0R, low = CAN_RDL0R, high = CAN_RDH0R;
  frame->extended = (ir & CAN_IR_IDE) != 0;
  frame->id = frame->extended ? ir >> 3 : ir >> 21;
  frame->len = (uint8_t)(CAN_RDT0R & 0xFu);
  if (frame->len > 8) frame->len = 8;  // DLC 9..15 mean 8 bytes in classic CAN
  for (int k = 0; k < 4; k++) {
    frame->data[k] = (uint8_t)(low >> 8 * k);
    frame->data[4 + k] = (uint8_t)(high >> 8 * k);
  }
  // release the output mailbox (the next frame moves up) and clear an overrun, in one write
  CAN_RF0R = CAN_RF0R_RFOM | overrun;
  return 1;
}

uint32_t f405_can_overruns(void) {
  return g_overruns;
}
