// can_double.h: the register-level test double of the STM32F405's bxCAN1 (can_double.c), forced
// into the driver's build (-include) with -DF405_CAN1_BASE=... -DGPIOB_BASE=... -DF405_POLL()=...
#ifndef F405_CAN_DOUBLE_H
#define F405_CAN_DOUBLE_H

#include <stdint.h>

extern uint32_t g_can_regs[0x320 / 4];    // CAN1's registers, 0x000 .. 0x31C
extern uint32_t g_gpiob_regs[0x28 / 4];   // GPIOB's, 0x00 .. 0x24
void can_model_step(void);

#endif
