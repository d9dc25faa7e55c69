// board_posix.h: what the Linux board's parts share (board_posix.c, board_slcan.c).
#ifndef BOARD_POSIX_H
#define BOARD_POSIX_H

long board_posix_reply_ms(void);            // reply_ms=N: how long a bus's answer may take
void board_posix_bus_used(void);            // a bus was written this tick (lock-step's idle wait)
int board_posix_can_open(const char* path); // can=PATH: the SLCAN adapter's tty; 0, or -1 (said why)

#endif  // BOARD_POSIX_H
