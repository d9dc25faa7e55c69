// startup.c: reset, vector table, faults and semihosting for the MPS2 boards (AN386
// Cortex-M4F, AN500 Cortex-M7).
//
// The reset handler enables the FPU (every float instruction faults until CPACR grants
// coprocessors 10 and 11), copies .data from flash, zeroes .bss, runs main and stops with its
// return value. A fault stops with code 99, so a crash under QEMU ends the run at once.
#include <stdint.h>

#include "board.h"

int main(void);

// symbols of the linker script
extern uint32_t __data_start[], __data_end[], __data_load[], __bss_start[], __bss_end[];
extern uint32_t __stack_bottom[], __stack_top[];

#define CPACR (*(volatile uint32_t*)0xE000ED88u)
#define SEMIHOSTING_SYS_WRITE0 0x04
#define SEMIHOSTING_SYS_GET_CMDLINE 0x15
#define SEMIHOSTING_SYS_EXIT_EXTENDED 0x20
#define ADP_STOPPED_APPLICATION_EXIT 0x20026
#define FAULT_CODE 99
#define STACK_PAINT 0xA5A5A5A5u

static int semihost(int op, const void* arg) {
  register int r0 __asm__("r0") = op;
  register const void* r1 __asm__("r1") = arg;
  __asm__ volatile("bkpt 0xAB" : "+r"(r0) : "r"(r1) : "memory");
  return r0;
}

void board_write(const char* text) {
  semihost(SEMIHOSTING_SYS_WRITE0, text);
}

void board_write_int(long value) {
  char text[24], *p = text + sizeof text - 1;
  unsigned long magnitude = value < 0 ? 0ul - (unsigned long)value : (unsigned long)value;
  *p = 0;
  do {
    *--p = (char)('0' + magnitude % 10);
    magnitude /= 10;
  } while (magnitude);
  if (value < 0) *--p = '-';
  board_write(p);
}

int board_cmdline(char* text, unsigned size) {
  uint32_t block[2] = {(uint32_t)(uintptr_t)text, size};
  if (size == 0 || semihost(SEMIHOSTING_SYS_GET_CMDLINE, block) != 0) return -1;
  return (int)block[1];
}

void board_stop(int code) {
  const uint32_t block[2] = {ADP_STOPPED_APPLICATION_EXIT, (uint32_t)code};
  for (;;) semihost(SEMIHOSTING_SYS_EXIT_EXTENDED, block);
}

// paint from the bottom of the stack to a little below the current frame
void board_stack_paint(void) {
  uint32_t* sp;
  __asm__ volatile("mov %0, sp" : "=r"(sp));
  for (uint32_t* p = __stack_bottom; p < sp - 16; p++) *p = STACK_PAINT;
}

unsigned board_stack_used(void) {
  const uint32_t* p = __stack_bottom;
  while (p < __stack_top && *p == STACK_PAINT) p++;
  return (unsigned)((uintptr_t)__stack_top - (uintptr_t)p);
}

void mcu_reset(void) {
  CPACR |= 0xFu << 20;
  __asm__ volatile("dsb\n\tisb" ::: "memory");
  for (uint32_t *src = __data_load, *dst = __data_start; dst < __data_end;) *dst++ = *src++;
  for (uint32_t* dst = __bss_start; dst < __bss_end;) *dst++ = 0;
  int code = main();
  board_clock_report();
  board_stop(code);
}

static void mcu_fault(void) {
  board_write("servodyn-mcu: fault\n");
  board_stop(FAULT_CODE);
}

// interrupt handlers a program may define (board_io.c does); until then a stray one stops
void board_systick_isr(void) __attribute__((weak, alias("mcu_fault")));
void board_uart0_rx_isr(void) __attribute__((weak, alias("mcu_fault")));
void board_uart1_rx_isr(void) __attribute__((weak, alias("mcu_fault")));   // the HIL sync line
void board_uart2_rx_isr(void) __attribute__((weak, alias("mcu_fault")));   // the host link (fw_link.c)
// a program without the control clock (the core's check, main.c) has no clock to report
static void no_report(void) {}
void board_clock_report(void) __attribute__((weak, alias("no_report")));

// the Cortex-M vector table: initial stack pointer, the system handlers, then the MPS2's
// interrupts (0: UART0 receive, 1: UART0 transmit, 2: UART1 receive, ...; QEMU hw/arm/mps2.c)
__attribute__((section(".vectors"), used))
static void (*const g_vectors[16 + 32])(void) = {
  (void (*)(void))(uintptr_t)__stack_top,
  mcu_reset,    // reset
  mcu_fault,    // NMI
  mcu_fault,    // hard fault
  mcu_fault,    // memory management fault
  mcu_fault,    // bus fault
  mcu_fault,    // usage fault
  0, 0, 0, 0,   // reserved
  mcu_fault,    // SVCall
  mcu_fault,    // debug monitor
  0,            // reserved
  mcu_fault,    // PendSV
  board_systick_isr,     // SysTick
  board_uart0_rx_isr,    // IRQ 0: UART0 receive
  mcu_fault,             // IRQ 1: UART0 transmit
  board_uart1_rx_isr,    // IRQ 2: UART1 receive (board_io.c's, in a hardware-in-the-loop build)
  mcu_fault,             // IRQ 3: UART1 transmit
  board_uart2_rx_isr,    // IRQ 4: UART2 receive (the host link's line)
  [21 ... 47] = mcu_fault,
};
