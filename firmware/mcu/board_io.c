// board_io.c: SysTick control clock and UART0 driver for the MPS2 boards (CMSDK APB UART).
#include "board.h"

// SysTick (Armv7-M architecture reference manual, B3.3)
#define SYST_CSR (*(volatile uint32_t*)0xE000E010u)
#define SYST_RVR (*(volatile uint32_t*)0xE000E014u)
#define SYST_CVR (*(volatile uint32_t*)0xE000E018u)
#define SYST_ENABLE 1u
#define SYST_TICKINT 2u
#define SYST_CLKSOURCE 4u           // the processor clock

// NVIC
#define NVIC_ISER0 (*(volatile uint32_t*)0xE000E100u)
#define IRQ_UART0_RX 0

// CMSDK APB UART0 on the MPS2 (AN385/AN386/AN500 memory map)
#define UART0_BASE 0x40004000u
#define UART_DATA (*(volatile uint32_t*)(UART0_BASE + 0x00u))
#define UART_STATE (*(volatile uint32_t*)(UART0_BASE + 0x04u))
#define UART_CTRL (*(volatile uint32_t*)(UART0_BASE + 0x08u))
#define UART_INTCLEAR (*(volatile uint32_t*)(UART0_BASE + 0x0Cu))
#define UART_BAUDDIV (*(volatile uint32_t*)(UART0_BASE + 0x10u))
#define UART_STATE_TXFULL 1u
#define UART_STATE_RXFULL 2u
#define UART_CTRL_TXEN 1u
#define UART_CTRL_RXEN 2u
#define UART_CTRL_RXINTEN 8u
#define UART_INT_RX 2u
#define UART_BAUDDIV_MIN 16u        // the CMSDK UART's smallest divider

#define RX_SIZE 512u                // a power of two; more than the largest reply of a tick

static volatile uint32_t g_ticks;
static uint32_t g_period;

static volatile uint8_t g_rx[RX_SIZE];
static volatile uint32_t g_rx_head, g_rx_tail, g_rx_overruns;

void board_systick_isr(void) {
  g_ticks++;
}

void board_clock_start(uint32_t period) {
  g_period = period;
  g_ticks = 0;
  SYST_CSR = 0;
  SYST_RVR = period - 1u;
  SYST_CVR = 0;
  SYST_CSR = SYST_ENABLE | SYST_TICKINT | SYST_CLKSOURCE;
}

uint32_t board_clock_now(void) {
  uint32_t ticks, value;
  do {                               // a period boundary between the two reads: read again
    ticks = g_ticks;
    value = SYST_CVR;
  } while (ticks != g_ticks);
  return ticks * g_period + (g_period - 1u - value);
}

uint32_t board_clock_ticks(void) {
  return g_ticks;
}

void board_clock_wait(void) {
  uint32_t start = g_ticks;
  while (g_ticks == start) __asm__ volatile("wfi");
}

void board_tick_begin(void) {}

void board_clock_hold(void) {
  SYST_CSR &= ~SYST_ENABLE;
}

void board_clock_release(void) {
  SYST_CSR |= SYST_ENABLE;
}

void board_uart0_rx_isr(void) {
  // clear first, then drain: a byte that lands after the last look raises the interrupt again
  UART_INTCLEAR = UART_INT_RX;
  while (UART_STATE & UART_STATE_RXFULL) {
    uint8_t byte = (uint8_t)UART_DATA;
    uint32_t next = (g_rx_head + 1u) & (RX_SIZE - 1u);
    if (next == g_rx_tail) {
      g_rx_overruns++;
    } else {
      g_rx[g_rx_head] = byte;
      g_rx_head = next;
    }
  }
}

void board_uart_init(uint32_t baud) {
  uint32_t div = BOARD_CPU_HZ / baud;
  UART_CTRL = 0;
  UART_BAUDDIV = div < UART_BAUDDIV_MIN ? UART_BAUDDIV_MIN : div;
  g_rx_head = g_rx_tail = 0;
  UART_CTRL = UART_CTRL_TXEN | UART_CTRL_RXEN | UART_CTRL_RXINTEN;
  // an empty read: QEMU's model asks its character backend for input again only when the data
  // register is read, and it stopped asking while the receiver was off
  (void)UART_DATA;
  NVIC_ISER0 = 1u << IRQ_UART0_RX;
}

void board_uart_write(const uint8_t* data, size_t n) {
  for (size_t k = 0; k < n; k++) {
    while (UART_STATE & UART_STATE_TXFULL) {
    }
    UART_DATA = data[k];
  }
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

#define REPLY_POLLS 30000000u       // polls of the receive buffer before a servo is silent

int board_uart_wait(size_t want) {
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
