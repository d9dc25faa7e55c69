// board_link.c: the host link's line on the MPS2 boards (board.h's board_link_*), for the general
// application (firmware/app/fw_link.c) alone: the generated robot's image has no link.
#include <stddef.h>
#include <stdint.h>

#include "board.h"

#define NVIC_ISER0 (*(volatile uint32_t*)0xE000E100u)
#define UART_STATE_TXFULL 1u
#define UART_STATE_RXFULL 2u
#define UART_CTRL_TXEN 1u
#define UART_CTRL_RXEN 2u
#define UART_CTRL_RXINTEN 8u
#define UART_INT_RX 2u
#define UART_BAUDDIV_MIN 16u        // the CMSDK UART's smallest divider

// CMSDK APB UART2 (-serial #2 under QEMU; IRQ 4 its receive): each byte its interrupt takes goes
// into a ring the tick empties (QEMU's model hands over the next byte only once one is read, so a
// polled receiver would take one byte a tick).
#define UART2_BASE 0x40006000u
#define UART2_DATA (*(volatile uint32_t*)(UART2_BASE + 0x00u))
#define UART2_STATE (*(volatile uint32_t*)(UART2_BASE + 0x04u))
#define UART2_CTRL (*(volatile uint32_t*)(UART2_BASE + 0x08u))
#define UART2_INTCLEAR (*(volatile uint32_t*)(UART2_BASE + 0x0Cu))
#define UART2_BAUDDIV (*(volatile uint32_t*)(UART2_BASE + 0x10u))
#define IRQ_UART2_RX 4
#define LINK_RX_SIZE 1024u             // a window of requests: 8 frames of up to 250 bytes fit

static uint8_t g_link_rx[LINK_RX_SIZE];
static volatile uint32_t g_link_head, g_link_tail;   // written by the ISR, read by the tick

void board_uart2_rx_isr(void) {
  UART2_INTCLEAR = UART_INT_RX;
  while (UART2_STATE & UART_STATE_RXFULL) {
    uint8_t byte = (uint8_t)UART2_DATA;
    if (g_link_head - g_link_tail < LINK_RX_SIZE) g_link_rx[g_link_head++ % LINK_RX_SIZE] = byte;
  }
}

void board_link_init(void) {
  UART2_CTRL = 0;
  UART2_BAUDDIV = UART_BAUDDIV_MIN;
  g_link_head = g_link_tail = 0;
  UART2_CTRL = UART_CTRL_TXEN | UART_CTRL_RXEN | UART_CTRL_RXINTEN;
  (void)UART2_DATA;                 // as for UART0: QEMU asks its backend again on a read
  NVIC_ISER0 = 1u << IRQ_UART2_RX;
}

int board_link_write(const uint8_t* data, size_t n) {
  for (size_t k = 0; k < n; k++) {
    while (UART2_STATE & UART_STATE_TXFULL) {
    }
    UART2_DATA = data[k];
  }
  return 1;
}

size_t board_link_take(uint8_t* out, size_t cap) {
  size_t n = 0;
  while (n < cap && g_link_tail != g_link_head) out[n++] = g_link_rx[g_link_tail++ % LINK_RX_SIZE];
  return n;
}
