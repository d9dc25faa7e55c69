// startup.c: reset, vector table, faults and the text channel of the STM32F405 board.
//
// Reset: the FPU on (CPACR grants coprocessors 10 and 11), the clock tree to 168 MHz
// (clock.c's f405_clock_init), .data copied from flash, .bss zeroed, main, the board's clock
// report, stop with main's return value. A fault stops with code 99.
//
// The text channel: in the hardware-in-the-loop build QEMU runs (BOARD_HIL) it is Arm semihosting,
// as on the MPS2 boards (QEMU hands the exit code to the host). On a board with no debugger
// attached a semihosting call (bkpt 0xAB) is a HardFault, so the build for silicon writes the
// report to USART2 (PA2, 115200 8N1: the console), takes its command line from nothing, and stops
// by sleeping forever (the application has switched every servo's torque off before it returns).
#include <stdint.h>

#include "board.h"
#include "f405.h"
#include "stm32f405.h"

int main(void);

extern uint32_t __data_start[], __data_end[], __data_load[], __bss_start[], __bss_end[];
extern uint32_t __stack_bottom[], __stack_top[];

#define FAULT_CODE 99
#define STACK_PAINT 0xA5A5A5A5u

#ifdef BOARD_HIL
#define SEMIHOSTING_SYS_WRITE0 0x04
#define SEMIHOSTING_SYS_GET_CMDLINE 0x15
#define SEMIHOSTING_SYS_EXIT_EXTENDED 0x20
#define ADP_STOPPED_APPLICATION_EXIT 0x20026

static int semihost(int op, const void* arg) {
  register int r0 __asm__("r0") = op;
  register const void* r1 __asm__("r1") = arg;
  __asm__ volatile("bkpt 0xAB" : "+r"(r0) : "r"(r1) : "memory");
  return r0;
}

void board_write(const char* text) {
  semihost(SEMIHOSTING_SYS_WRITE0, text);
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
#else
void board_write(const char* text) {
  f405_console_write(text);
}

int board_cmdline(char* text, unsigned size) {
  if (size) text[0] = 0;
  return 0;
}

void board_stop(int code) {
  board_write("servodyn-board: stopped code=");
  board_write_int(code);
  board_write("\n");
  for (;;) __asm__ volatile("wfi");
}
#endif

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

void f405_reset(void) {
  SCB_CPACR |= 0xFu << 20;
  __asm__ volatile("dsb\n\tisb" ::: "memory");
  SCB_VTOR = 0x08000000u;           // the table in flash (QEMU and the chip also alias it at 0)
  for (uint32_t *src = __data_load, *dst = __data_start; dst < __data_end;) *dst++ = *src++;
  for (uint32_t* dst = __bss_start; dst < __bss_end;) *dst++ = 0;
  int clock = f405_clock_init();
  f405_console_init();
  if (clock == F405_CLOCK_FAILED) {  // silicon without a running PLL: every baud rate is wrong
    board_write("servodyn-board: clock tree not at 168 MHz\n");
    board_stop(16);                   // FW_FAULT_SETUP
  }
  int code = main();
  board_clock_report();
  board_stop(code);
}

static void f405_fault(void) {
  board_write("servodyn-mcu: fault\n");
  board_stop(FAULT_CODE);
}

// the handlers the board layer defines; a stray interrupt stops
void board_systick_isr(void) __attribute__((weak, alias("f405_fault")));
void f405_usart1_isr(void) __attribute__((weak, alias("f405_fault")));
void f405_usart2_isr(void) __attribute__((weak, alias("f405_fault")));
void f405_usart3_isr(void) __attribute__((weak, alias("f405_fault")));   // the host link (board_link.c)

// the Cortex-M4 system vectors, then the F405's 82 interrupts (RM0090 table 61)
__attribute__((section(".vectors"), used))
static void (*const g_vectors[16 + 82])(void) = {
  (void (*)(void))(uintptr_t)__stack_top,
  f405_reset,   // reset
  f405_fault,   // NMI
  f405_fault,   // hard fault
  f405_fault,   // memory management fault
  f405_fault,   // bus fault
  f405_fault,   // usage fault
  0, 0, 0, 0,   // reserved
  f405_fault,   // SVCall
  f405_fault,   // debug monitor
  0,            // reserved
  f405_fault,   // PendSV
  board_systick_isr,                    // SysTick
  [16 ... 16 + 36] = f405_fault,        // IRQ 0..36 (CAN1 19..22 polled: can.c)
  [16 + IRQ_USART1] = f405_usart1_isr,  // IRQ 37: the Dynamixel bus
  [16 + IRQ_USART2] = f405_usart2_isr,  // IRQ 38: the sync line (BOARD_HIL) / console
  [16 + IRQ_USART3] = f405_usart3_isr,  // IRQ 39: the host link (the general application)
  [16 + 40 ... 16 + 81] = f405_fault,
};
