// f405.h: the STM32F405 board layer's own functions, beside board.h's (which the application uses).
#ifndef F405_H
#define F405_H

#include <stdint.h>

// The clock tree to 168 MHz (clock.c). Every ready-flag wait is bounded. The result:
enum {
  F405_CLOCK_HSE = 0,       // PLL on the 8 MHz crystal: SYSCLK 168, APB1 42, APB2 84 MHz
  F405_CLOCK_HSI = 1,       // no crystal started: PLL on the 16 MHz internal oscillator, same clocks
  F405_CLOCK_EMULATED = 2,  // RCC reads 0 (QEMU: unimplemented; the core clock is 168 MHz anyway)
  F405_CLOCK_FAILED = 3,    // silicon, the PLL did not lock: still on HSI 16 MHz (start-up stops)
};
int f405_clock_init(void);
// Whether the chip is QEMU's (RCC_CR reads 0: on silicon HSION/HSIRDY are always set).
int f405_emulated(void);

// A pin's mode (GPIO_MODE_*, 2 bits) and alternate function (4 bits), at very high speed
// (board_io.c); the USART's baud rate divider from its bus clock (OVER8 = 0: at least 16).
void f405_pin(uint32_t port, uint32_t n, uint32_t mode, uint32_t af);
uint32_t f405_brr(uint32_t pclk, uint32_t baud);
#define F405_APB1_HZ 42000000u         // USART2/3, bxCAN
#define F405_APB2_HZ 84000000u         // USART1

// The console, USART2 at 115200 8N1 on PA2 (transmit only; the build for silicon's board_write).
void f405_console_init(void);
void f405_console_write(const char* text);

#endif  // F405_H
