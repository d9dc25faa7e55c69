// board_systick.h: the control clock that is the same on every Cortex-M board: SysTick counting
// the control period (board.h's board_systick_isr, board_clock_now/ticks/wait). Included by
// exactly one file of an image, the board's clock (firmware/mcu/board_io.c for MPS2,
// firmware/boards/stm32f405/clock.c for the STM32F405), which defines the SYST_* registers before
// including it and calls systick_start(period) from its board_clock_start.
#ifndef MCU_BOARD_SYSTICK_H
#define MCU_BOARD_SYSTICK_H

#include "board.h"

static volatile uint32_t g_ticks;
static uint32_t g_period;

void board_systick_isr(void) {
  g_ticks++;
}

static void systick_start(uint32_t period) {
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

#endif
