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

#endif  // MCU_BOARD_H
