// board_can.c: the STM32F405's CAN bus for the general application (fw_can.h's board_can_*) on
// bxCAN1 (can.c): every standard frame accepted (filter bank 0, mask 0), polled. The receive FIFO
// holds three frames, fewer than a tick's answers, so whatever waits (a full transmit mailbox, an
// answer) first moves the FIFO's frames into a ring of its own. Compiled into the F405 images and
// unit-checked with the register double; no QEMU machine runs it (can.h).
#include "can.h"
#include "fw_can.h"
#include "stm32f405.h"

#define RING 32u                      // frames received and not yet taken
#define SEND_POLLS 20000u             // a mailbox frees within one frame's time (~135 us at 1 Mbit/s)
#define REPLY_POLLS 200000u           // the motors' answers: a few ms of polls at 168 MHz

static f405_can_frame g_ring[RING];
static unsigned g_head, g_count, g_lost;
static int g_open;

// the FIFO's frames into the ring (extended frames dropped: the motors speak 11-bit ids)
static void pump(void) {
  f405_can_frame f;
  while (f405_can_receive(&f)) {
    if (f.extended) continue;
    if (g_count == RING) {
      g_lost++;
      continue;
    }
    g_ring[(g_head + g_count++) % RING] = f;
  }
}

int board_can_open(uint32_t bitrate) {
  g_open = f405_can_init(bitrate, 0) == F405_CAN_OK && f405_can_filter(0, 0, 0, 0) == F405_CAN_OK;
  g_head = g_count = g_lost = 0;
  return g_open;
}

int board_can_send(uint16_t id, const uint8_t* data, uint8_t len) {
  if (!g_open || len > 8) return 0;
  f405_can_frame f = {.id = id, .extended = 0, .len = len};
  for (uint8_t k = 0; k < len; k++) f.data[k] = data[k];
  for (uint32_t n = 0; n < SEND_POLLS; n++) {
    int r = f405_can_send(&f);
    if (r == F405_CAN_OK) return 1;
    if (r != F405_CAN_FULL) return 0;
    pump();
    F405_POLL();
  }
  return 0;                           // no mailbox freed: no bus (bus-off, no transceiver)
}

int board_can_take(uint16_t* id, uint8_t* data, uint8_t* len) {
  if (!g_open) return 0;
  pump();
  if (!g_count) return 0;
  const f405_can_frame* f = &g_ring[g_head];
  g_head = (g_head + 1) % RING;
  g_count--;
  *id = (uint16_t)f->id;
  *len = f->len;
  for (uint8_t k = 0; k < f->len; k++) data[k] = f->data[k];
  return 1;
}

int board_can_wait(void) {
  if (!g_open) return 0;
  for (uint32_t n = 0; n < REPLY_POLLS; n++) {
    pump();
    if (g_count) return 1;
    F405_POLL();
  }
  return 0;
}
