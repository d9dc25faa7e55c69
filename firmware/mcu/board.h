// board.h: the little the firmware needs from the board: start-up, a text channel to the
// host and a way to stop with an exit code (Arm semihosting, so QEMU reports it).
#ifndef MCU_BOARD_H
#define MCU_BOARD_H

// Write a zero-terminated string to the host's console (semihosting SYS_WRITE0).
void board_write(const char* text);

// Write a decimal number.
void board_write_int(long value);

// Stop and report code to the host (semihosting SYS_EXIT_EXTENDED); never returns.
void board_stop(int code) __attribute__((noreturn));

// Fill the unused stack with a pattern; board_stack_used() then tells the deepest use since.
void board_stack_paint(void);
unsigned board_stack_used(void);

// The command line QEMU passes (semihosting SYS_GET_CMDLINE) into text; its length, or -1.
int board_cmdline(char* text, unsigned size);

//---------------------------------- board_io.c: clock and UART ---------------------------------
#include <stddef.h>
#include <stdint.h>

#ifndef BOARD_CPU_HZ
#define BOARD_CPU_HZ 25000000u      // MPS2: SysTick counts the 25 MHz processor clock
#endif                              // (the native build counts nanoseconds: 1e9)

// The control clock: a SysTick interrupt every `period` processor clock counts.
void board_clock_start(uint32_t period);
// Counts since board_clock_start (wraps after 2^32 counts, 172 s at 25 MHz).
uint32_t board_clock_now(void);
// Periods begun since board_clock_start.
uint32_t board_clock_ticks(void);
// Sleep until the next period begins.
void board_clock_wait(void);
// A tick begins now: after the wait, or at once when it catches up on a late plan (the native
// board times each tick from here for its log; nothing to do on a microcontroller).
void board_tick_begin(void);
// Stop and restart the clock (the period's position is kept). The lock-stepped simulated bus
// answers in no time of the emulated clock; the firmware holds the clock while it waits so that
// a tick costs the instructions it executes, and no more, however slow the host is.
void board_clock_hold(void);
void board_clock_release(void);
// The board's own report line, after the application's (start-up calls it when main returns):
//   servodyn-board: clock ticks=N period=P cpu_hz=F ref_us=T
// the periods begun, the configured period in clock counts, and the emulated time the clock ran
// (not held) in microseconds by an independent timer (MPS2: CMSDK timer 0; STM32F405: TIM2).
// N x P / F s = T us when every period's interrupt is taken (tests/test_f405_clock.py).
void board_clock_report(void);

// The bus UART (MPS2: CMSDK UART0, 8N1; STM32F405: USART1, half duplex with its direction pin,
// firmware/boards/stm32f405/board_io.c) at `baud`, received bytes buffered by its interrupt.
void board_uart_init(uint32_t baud);
void board_uart_write(const uint8_t* data, size_t n);
// Take one received byte: 1, or 0 when none has arrived.
int board_uart_read(uint8_t* byte);
// Take up to cap received bytes into out; how many.
size_t board_uart_take(uint8_t* out, size_t cap);
// Bytes received and not yet taken.
size_t board_uart_available(void);
// Wait until at least `want` bytes are there to take: 1, or 0 when the servos are taken for silent
// (MPS2: after a fixed number of polls; Linux: a reply timeout, waiting in poll()).
// A hardware-in-the-loop build (BOARD_HIL, the images QEMU runs) first sleeps, executing nothing,
// until the bytes are there or the simulated bus has said on its sync line (MPS2 UART1, STM32F405
// USART2) that it has read everything sent and answered all it will; only then do the polls
// count (firmware/mcu/board_uart_ring.h). The emulated
// clock cannot run while the host is slow to answer, so a late reply is never a timeout.
int board_uart_wait(size_t want);
// Drop whatever has been received and not taken.
void board_uart_flush(void);
// Bytes lost because the receive buffer was full.
uint32_t board_uart_overruns(void);

//---------------------------------- the host link's line (fw_link.c) ---------------------------
// The second byte stream, to the host (docs/host-link.md, "The line"). Linux: a pseudo-terminal or
// any character device or socket named on the command line (link=PATH); a microcontroller: a
// USART (to come).
void board_link_init(void);
// Send a frame's bytes. A line with no room for them drops the frame (telemetry is news; the host
// sends a request again): 1 sent, 0 dropped.
int board_link_write(const uint8_t* data, size_t n);
// Take up to cap received bytes into out; how many (0: none waiting).
size_t board_link_take(uint8_t* out, size_t cap);

#endif  // MCU_BOARD_H
