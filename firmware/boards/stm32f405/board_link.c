// board_link.c: the host link's line on the STM32F405 (board.h's board_link_*), for the general
// application (firmware/app/fw_link.c) alone: the generated robot's image has no link.
//
// USART3 on PB10 (TX) / PB11 (RX), alternate function 7, 2 Mbps 8N1: the pins a board brings out
// as its serial port (the Feather STM32F405's TX/RX, D1/D0), away from the bus (USART1, PA8/PA9),
// the console (USART2, PA2/PA3) and CAN1 (PB8/PB9); QEMU's netduinoplus2 puts USART3 on -serial #2,
// the slot the MPS2 image's link has, so the host side (host/hil.py run_qemu_link) is the same.
// USART3 sits on APB1 = 42 MHz: BRR 21 is exactly 2 Mbps (3 Mbps, BRR 14, is exact too; 4 Mbps is
// not: USART1/6 on APB2 have it, USART1 is the bus). A USB-UART adapter on the host side
// (FT232R, CP2102N: 3 Mbaud; CH340: 2 Mbaud) carries it.
//
// Receive: the RXNE interrupt into the ring the tick empties (board_link_ring.h). Transmit:
// polled, TXE before each byte (QEMU 7.2 raises no TXE interrupt; the telemetry frame of a tick
// is about 123 bytes, 615 us of the line at 2 Mbps, which the polling waits out on silicon -- a
// DMA stream would free it, silicon-only since QEMU models no DMA).
#include "board.h"
#include "f405.h"
#include "stm32f405.h"

#define LINK_BAUD 2000000u
#define LINK_TX 10u                    // PB10
#define LINK_RX 11u                    // PB11

#include "board_link_ring.h"

void f405_usart3_isr(void) {
  uint32_t sr;
  while ((sr = USART_SR(USART3_BASE)) & (USART_SR_RXNE | USART_SR_ORE)) {
    uint8_t byte = (uint8_t)USART_DR(USART3_BASE);   // SR then DR clears ORE too
    if (sr & USART_SR_ORE) g_link_overruns++;        // silicon only: a byte lost in the USART
    if (sr & USART_SR_RXNE) link_rx_push(byte);
  }
}

void board_link_init(void) {
  RCC_APB1ENR |= RCC_APB1ENR_USART3;
  (void)RCC_APB1ENR;                   // RM0090 errata 2.1.13: a read before the first access
  f405_pin(GPIOB_BASE, LINK_TX, GPIO_MODE_AF, 7);
  f405_pin(GPIOB_BASE, LINK_RX, GPIO_MODE_AF, 7);
  GPIO_PUPDR(GPIOB_BASE) = (GPIO_PUPDR(GPIOB_BASE) & ~(3u << 2 * LINK_RX)) | GPIO_PULL_UP << 2 * LINK_RX;
  USART_CR1(USART3_BASE) = 0;
  USART_BRR(USART3_BASE) = f405_brr(F405_APB1_HZ, LINK_BAUD);
  link_rx_reset();
  USART_CR1(USART3_BASE) = USART_CR1_UE | USART_CR1_TE | USART_CR1_RE | USART_CR1_RXNEIE;
  (void)USART_DR(USART3_BASE);         // QEMU asks its backend for input again on a DR read
  NVIC_ENABLE(IRQ_USART3);
}

int board_link_write(const uint8_t* data, size_t n) {
  for (size_t k = 0; k < n; k++) {
    while (!(USART_SR(USART3_BASE) & USART_SR_TXE)) {
    }
    USART_DR(USART3_BASE) = data[k];
  }
  return 1;
}
