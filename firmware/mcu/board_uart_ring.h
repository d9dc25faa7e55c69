// board_uart_ring.h: the part of a bus UART driver that is the same on every board: the receive
// ring its interrupt fills, the hardware-in-the-loop sync line's records and the reply wait
// (board.h's board_uart_read/take/available/wait/flush/overruns). Included by exactly one file of
// an image, the board's UART driver (firmware/mcu/board_io.c for MPS2,
// firmware/boards/stm32f405/board_io.c for the STM32F405), which defines before including it:
//   SYNC_IRQ_ON(), SYNC_IRQ_OFF()   enable / disable the sync line's receive interrupt (BOARD_HIL)
//   REPLY_POLLS                      if not the MPS2's 30,000,000 polls
//   BUS_IRQ_OFF(), BUS_IRQ_ON()      (BOARD_HIL) mask the bus's receive interrupt from the end of a
//                                    write until hil_wait, where the clock is held: QEMU passes the
//                                    written bytes on at once, and the host's reply could otherwise
//                                    interrupt the instructions between the write and the hold
// and calls ring_push(byte) from its bus receive interrupt, sync_byte(byte) from the sync line's.
#ifndef MCU_BOARD_UART_RING_H
#define MCU_BOARD_UART_RING_H

#include "board.h"

#define RX_SIZE 512u                // a power of two; more than the largest reply of a tick
#ifndef REPLY_POLLS                 // polls of the receive buffer before a servo is silent (a
#define REPLY_POLLS 30000000u       // board may set its own before including this file)
#endif

static volatile uint8_t g_rx[RX_SIZE];
static volatile uint32_t g_rx_head, g_rx_tail, g_rx_overruns;

#ifdef BOARD_HIL
#define SYNC_RECORD 8u              // the host's record: bytes read, bytes sent (uint32 LE each)
static volatile uint32_t g_hil_sent, g_hil_received;     // bytes written to the bus, arrived on it
static volatile uint32_t g_host_read, g_host_sent;       // the host's last complete record
static uint8_t g_sync[SYNC_RECORD];
static uint32_t g_sync_got;

static void sync_byte(uint8_t byte) {
  g_sync[g_sync_got++] = byte;
  if (g_sync_got == SYNC_RECORD) {
    g_sync_got = 0;
    g_host_read = (uint32_t)g_sync[0] | (uint32_t)g_sync[1] << 8 | (uint32_t)g_sync[2] << 16 |
                  (uint32_t)g_sync[3] << 24;
    g_host_sent = (uint32_t)g_sync[4] | (uint32_t)g_sync[5] << 8 | (uint32_t)g_sync[6] << 16 |
                  (uint32_t)g_sync[7] << 24;
  }
}

// Sleep until `want` bytes are there to take, or the simulated bus is quiet: it has read every
// byte written to it (so it has seen the whole request) and every byte it sent has arrived (so
// none is still on its way through QEMU). The check and the WFI are one step with interrupts
// masked: an interrupt that comes between them leaves WFI at once, then is taken when unmasked.
// The sync line's interrupt is enabled only here, where the clock is held (bus_receive), so its
// records cost no instructions of a tick; the records are cumulative, so reading them late is
// reading them all.
#ifndef BUS_IRQ_OFF
#define BUS_IRQ_OFF() ((void)0)
#define BUS_IRQ_ON() ((void)0)
#endif
static void hil_wait(size_t want) {
  BUS_IRQ_ON();
  SYNC_IRQ_ON();
  for (;;) {
    __asm__ volatile("cpsid i" ::: "memory");
    int done = board_uart_available() >= want ||
               (g_host_read == g_hil_sent && g_host_sent == g_hil_received);
    if (!done) __asm__ volatile("dsb\n\twfi" ::: "memory");
    if (done) SYNC_IRQ_OFF();
    __asm__ volatile("cpsie i" ::: "memory");
    if (done) return;
  }
}
#endif

// one byte from the bus, in its receive interrupt
static inline void ring_push(uint8_t byte) {
#ifdef BOARD_HIL
  g_hil_received++;                // kept or lost to an overrun, the host sent it
#endif
  uint32_t next = (g_rx_head + 1u) & (RX_SIZE - 1u);
  if (next == g_rx_tail) {
    g_rx_overruns++;
  } else {
    g_rx[g_rx_head] = byte;
    g_rx_head = next;
  }
}

// after n bytes were written to the bus
static inline void ring_sent(size_t n) {
#ifdef BOARD_HIL
  BUS_IRQ_OFF();
  g_hil_sent += (uint32_t)n;
#else
  (void)n;
#endif
}

int board_uart_read(uint8_t* byte) {
  uint32_t tail = g_rx_tail;
  if (tail == g_rx_head) return 0;
  *byte = g_rx[tail];
  g_rx_tail = (tail + 1u) & (RX_SIZE - 1u);
  return 1;
}

size_t board_uart_take(uint8_t* out, size_t cap) {
  uint32_t tail = g_rx_tail, head = g_rx_head;
  size_t n = 0;
  while (tail != head && n < cap) {
    out[n++] = g_rx[tail];
    tail = (tail + 1u) & (RX_SIZE - 1u);
  }
  g_rx_tail = tail;
  return n;
}

size_t board_uart_available(void) {
  return (g_rx_head - g_rx_tail) & (RX_SIZE - 1u);
}

int board_uart_wait(size_t want) {
#ifdef BOARD_HIL
  hil_wait(want);                   // the host's reply is all there, or nothing more is coming
#endif
  for (uint32_t polls = 0; polls < REPLY_POLLS; polls++)
    if (board_uart_available() >= want) return 1;
  return 0;
}

void board_uart_flush(void) {
  g_rx_tail = g_rx_head;
}

uint32_t board_uart_overruns(void) {
  return g_rx_overruns;
}

#endif  // MCU_BOARD_UART_RING_H
