// board_io.c: SysTick control clock and UART0 driver for the MPS2 boards (CMSDK APB UART).
//
// Hardware in the loop (BOARD_HIL, the images QEMU runs against the simulated bus): QEMU's
// -icount makes the emulated clock count instructions, so a board that polls its UART for a reply
// runs its clock, and its reply timeout, on for as long as the host takes to answer in wall time;
// a host slowed down by load then reads as a silent servo. There UART1 is a sync line from the
// simulated bus: after each chunk of bytes it has read from UART0 and answered, the host sends a
// record (two little-endian 32-bit counts: bytes read from the board, bytes sent to it since the
// start). board_uart_wait sleeps (WFI, no timer running: the emulated clock stands still) until
// the reply is there or the host has read all the board wrote and the board has received all the
// host sent: then nothing more is coming, and the board's own timeout runs on a quiet line, the
// same polls as on a board. A real board (no BOARD_HIL) has no sync line and its code is unchanged.
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
#define NVIC_ICER0 (*(volatile uint32_t*)0xE000E180u)
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

#ifdef BOARD_HIL
// UART1 on the MPS2, the sync line from the simulated bus (receive only)
#define UART1_BASE 0x40005000u
#define UART1_DATA (*(volatile uint32_t*)(UART1_BASE + 0x00u))
#define UART1_STATE (*(volatile uint32_t*)(UART1_BASE + 0x04u))
#define UART1_CTRL (*(volatile uint32_t*)(UART1_BASE + 0x08u))
#define UART1_INTCLEAR (*(volatile uint32_t*)(UART1_BASE + 0x0Cu))
#define UART1_BAUDDIV (*(volatile uint32_t*)(UART1_BASE + 0x10u))
#define IRQ_UART1_RX 2
#define SYNC_IRQ_ON() (NVIC_ISER0 = 1u << IRQ_UART1_RX)
#define SYNC_IRQ_OFF() (NVIC_ICER0 = 1u << IRQ_UART1_RX)
// the bus's receive interrupt is taken only in hil_wait, where the clock is held: the host's
// reply can start arriving between the end of a write and the hold, and its interrupts counted
// in the tick then, a different number each run (board_uart_ring.h)
#define BUS_IRQ_OFF() (NVIC_ICER0 = 1u << IRQ_UART0_RX)
#define BUS_IRQ_ON() (NVIC_ISER0 = 1u << IRQ_UART0_RX)
#endif

// CMSDK APB timer 0: the emulated-time reference of board_clock_report (25 MHz, counts down;
// stopped while the control clock is held, so it counts the time the clock ran)
#define TIMER0_CTRL (*(volatile uint32_t*)0x40000000u)
#define TIMER0_VALUE (*(volatile uint32_t*)0x40000004u)
#define TIMER0_RELOAD (*(volatile uint32_t*)0x40000008u)

#include "board_uart_ring.h"

static volatile uint32_t g_ticks;
static uint32_t g_period;

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
  TIMER0_CTRL = 0;
  TIMER0_RELOAD = 0xFFFFFFFFu;
  TIMER0_VALUE = 0xFFFFFFFFu;
  TIMER0_CTRL = 1u;
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

// Sleep in WFI until the next SysTick. The hardware-in-the-loop build spins instead: under QEMU's
// -icount sleep=off (host/hil.py) a core that waits in WFI gets only every second SysTick
// interrupt, so each tick took two periods of emulated time (docs/boards.md, "Clocks under QEMU";
// tests/test_f405_clock.py). Spinning costs the host the idle instructions; the tick's own
// instructions, which the budget counts, are the same.
void board_clock_wait(void) {
  uint32_t start = g_ticks;
#ifdef BOARD_HIL
  while (g_ticks == start) __asm__ volatile("" ::: "memory");
#else
  while (g_ticks == start) __asm__ volatile("wfi");
#endif
}

void board_tick_begin(void) {}

void board_clock_hold(void) {
  SYST_CSR &= ~SYST_ENABLE;
  TIMER0_CTRL = 0;
}

void board_clock_release(void) {
  TIMER0_CTRL = 1u;
  SYST_CSR |= SYST_ENABLE;
}

void board_clock_report(void) {
  if (g_period == 0) return;        // the clock never started (a fault in the set-up)
  board_write("servodyn-board: clock ticks=");
  board_write_int((long)g_ticks);
  board_write(" period=");
  board_write_int((long)g_period);
  board_write(" cpu_hz=");
  board_write_int((long)BOARD_CPU_HZ);
  board_write(" ref_us=");
  board_write_int((long)((0xFFFFFFFFu - TIMER0_VALUE) / 25u));   // 25 counts a microsecond
  board_write("\n");
}

void board_uart0_rx_isr(void) {
  // clear first, then drain: a byte that lands after the last look raises the interrupt again
  UART_INTCLEAR = UART_INT_RX;
  while (UART_STATE & UART_STATE_RXFULL) ring_push((uint8_t)UART_DATA);
}

#ifdef BOARD_HIL
void board_uart1_rx_isr(void) {
  UART1_INTCLEAR = UART_INT_RX;
  while (UART1_STATE & UART_STATE_RXFULL) sync_byte((uint8_t)UART1_DATA);
}

static void sync_line_init(void) {
  UART1_CTRL = 0;
  UART1_BAUDDIV = UART_BAUDDIV_MIN;
  UART1_CTRL = UART_CTRL_RXEN | UART_CTRL_RXINTEN;
  (void)UART1_DATA;                 // as for UART0: QEMU asks its backend again on a read
}
#endif

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
#ifdef BOARD_HIL
  sync_line_init();
#endif
}

void board_uart_write(const uint8_t* data, size_t n) {
  for (size_t k = 0; k < n; k++) {
    while (UART_STATE & UART_STATE_TXFULL) {
    }
    UART_DATA = data[k];
  }
  ring_sent(n);
}
