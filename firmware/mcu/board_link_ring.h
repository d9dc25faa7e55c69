// board_link_ring.h: the host link's receive ring, the same on every microcontroller board: the
// line's receive interrupt puts each byte in (link_rx_push), the tick takes them out
// (board.h's board_link_take). QEMU's UART models hand over the next byte only once one is read,
// so a polled receiver would take one byte a tick. Included by exactly one file of an image, the
// board's host-link driver (firmware/mcu/board_link.c for MPS2,
// firmware/boards/stm32f405/board_link.c for the STM32F405).
#ifndef MCU_BOARD_LINK_RING_H
#define MCU_BOARD_LINK_RING_H

#include <string.h>

#include "board.h"

#define LINK_RX_SIZE 2048u             // a window of requests: 8 frames of up to 250 bytes fit

static uint8_t g_link_rx[LINK_RX_SIZE];
static volatile uint32_t g_link_head, g_link_tail;   // written by the ISR, read by the tick
static volatile uint32_t g_link_overruns;            // bytes lost to a full ring

static inline void link_rx_reset(void) {
  g_link_head = g_link_tail = 0;
}

// one byte from the line, in its receive interrupt (a full ring drops it: the host sends again)
static inline void link_rx_push(uint8_t byte) {
  if (g_link_head - g_link_tail < LINK_RX_SIZE) g_link_rx[g_link_head++ % LINK_RX_SIZE] = byte;
  else g_link_overruns++;
}

// at most two contiguous stretches of the ring, each one memcpy
size_t board_link_take(uint8_t* out, size_t cap) {
  uint32_t tail = g_link_tail, held = g_link_head - tail;
  size_t n = held < cap ? held : cap;
  size_t at = tail % LINK_RX_SIZE, first = n < LINK_RX_SIZE - at ? n : LINK_RX_SIZE - at;
  memcpy(out, g_link_rx + at, first);
  memcpy(out + first, g_link_rx, n - first);
  g_link_tail = tail + (uint32_t)n;
  return n;
}

#endif  // MCU_BOARD_LINK_RING_H
