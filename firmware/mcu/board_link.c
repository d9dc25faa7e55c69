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
// into the ring the tick empties (board_link_ring.h), transmit polled.
#define UART2_BASE 0x40006000u
#define UART2_DATA (*(volatile uint32_t*)(UART2_BASE + 0x00u))
#define UART2_STATE (*(volatile uint32_t*)(UART2_BASE + 0x04u))
#define UART2_CTRL (*(volatile uint32_t*)(UART2_BASE + 0x08u))
#define UART2_INTCLEAR (*(volatile uint32_t*)(UART2_BASE + 0x0Cu))
#define UART2_BAUDDIV (*(volatile uint32_t*)(UART2_BASE + 0x10u))
#define IRQ_UART2_RX 4

#include "board_link_ring.h"

void board_uart2_rx_isr(void) {
  UART2_INTCLEAR = UART_INT_RX;
  while (UART2_STATE & UART_STATE_RXFULL) link_rx_push((uint8_t)UART2_DATA);
}

void board_link_init(void) {
  UART2_CTRL = 0;
  UART2_BAUDDIV = UART_BAUDDIV_MIN;
  link_rx_reset();
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
