// board_io.c: the STM32F405's Dynamixel bus (USART1, half duplex) and its console / sync line
// (USART2), board.h's UART functions.
//
// Pins (RM0090 8, datasheet table 9, alternate function 7 = USART1..3):
//   PA9  USART1_TX, the bus: single-wire half duplex (CR3.HDSEL), open drain (an external pull-up
//        or the buffer's input: the USART leaves TX released while it receives)
//   PA8  the bus direction pin, push-pull: high while the board transmits (the external buffer
//        drives the bus: a 74LVC1T45's DIR, an RS-485 transceiver's DE and /RE), low otherwise
//   PA2  USART2_TX, PA3 USART2_RX: the console (115200 8N1) and, in the hardware-in-the-loop
//        build, the simulated bus's sync line (QEMU -serial #1)
// USART1 sits on APB2 = 84 MHz: BRR = 84 MHz / baud (OVER8 = 0) is exact at 1, 2, 3 and 4 Mbps.
//
// Receive: the RXNE interrupt into the ring (firmware/mcu/board_uart_ring.h). Transmit: polled,
// TXE before each byte and TC after the last, then the direction pin low -- QEMU 7.2 raises no
// TXE/TC interrupt, and polling keeps the turnaround exact on silicon (the servo answers after its
// Return Delay Time, 0 here: the pin must be low by the end of the stop bit).
// The echo: with HDSEL the chip's receiver hears the board's own bytes; the receiver is off while
// the board transmits. QEMU models neither HDSEL nor the echo, and drops bytes that arrive while
// RE is clear, so under QEMU (f405_emulated) the receiver stays on.
#include "board.h"
#include "f405.h"
#include "stm32f405.h"

#define DIR_PIN 8u                     // PA8
#define TC_POLLS 100000u               // a disabled USART never sets TC: do not hang on it
#define CONSOLE_BAUD 115200u

// The reply timeout: about 1 ms at 168 MHz (a poll is about 8 cycles), a control period. The
// replica's largest reply, 106 bytes at 4 Mbps, takes 265 us. (The MPS2's 30,000,000 polls last
// seconds; there the images run only in QEMU, after the sync line says the bus is quiet.)
#define REPLY_POLLS 20000u

#ifdef BOARD_HIL
#define SYNC_IRQ_ON() NVIC_ENABLE(IRQ_USART2)
#define SYNC_IRQ_OFF() NVIC_DISABLE(IRQ_USART2)
// QEMU's STM32 USART hands each transmitted byte to the host at once (a synchronous write), so
// the host's reply can start arriving in the few instructions between the end of a write and the
// clock's hold: its receive interrupts would then count in the tick, a different number each run
// (the read section's worst over 300 ticks: 4,687..5,650 instructions in five runs; 4,153..4,188
// with this). The bus interrupt is taken only in
// hil_wait, as the sync line's is; its bytes wait in QEMU meanwhile (one byte in DR, no overrun).
#define BUS_IRQ_OFF() NVIC_DISABLE(IRQ_USART1)
#define BUS_IRQ_ON() NVIC_ENABLE(IRQ_USART1)
#endif
#include "board_uart_ring.h"

// the bus's receive interrupt: each byte into the ring; an overrun (silicon only: QEMU holds the
// next byte until DR is read) lost one byte, counted with the ring's
void f405_usart1_isr(void) {
  uint32_t sr;
  while ((sr = USART_SR(USART1_BASE)) & (USART_SR_RXNE | USART_SR_ORE)) {
    uint8_t byte = (uint8_t)USART_DR(USART1_BASE);   // SR then DR clears ORE too
    if (sr & USART_SR_ORE) g_rx_overruns++;
    if (sr & USART_SR_RXNE) ring_push(byte);
  }
}

void f405_usart2_isr(void) {
  while (USART_SR(USART2_BASE) & USART_SR_RXNE) {
    uint8_t byte = (uint8_t)USART_DR(USART2_BASE);
#ifdef BOARD_HIL
    sync_byte(byte);
#else
    (void)byte;                        // the console takes no input
#endif
  }
}

uint32_t f405_brr(uint32_t pclk, uint32_t baud) {
  uint32_t d = (pclk + baud / 2u) / baud;
  return d < 16u ? 16u : d;            // OVER8 = 0: the divider is at least 16
}

// mode (2 bits), alternate function (4 bits) of pin n of a GPIO port, read-modify-write
void f405_pin(uint32_t port, uint32_t n, uint32_t mode, uint32_t af) {
  GPIO_MODER(port) = (GPIO_MODER(port) & ~(3u << 2 * n)) | mode << 2 * n;
  GPIO_OSPEEDR(port) |= 3u << 2 * n;   // very high speed: 4 Mbps edges
  if (mode != GPIO_MODE_AF) return;
  if (n < 8) GPIO_AFRL(port) = (GPIO_AFRL(port) & ~(15u << 4 * n)) | af << 4 * n;
  else GPIO_AFRH(port) = (GPIO_AFRH(port) & ~(15u << 4 * (n - 8))) | af << 4 * (n - 8);
}

void f405_console_init(void) {
  f405_pin(GPIOA_BASE, 2, GPIO_MODE_AF, 7);
  f405_pin(GPIOA_BASE, 3, GPIO_MODE_AF, 7);
  USART_CR1(USART2_BASE) = 0;
  USART_BRR(USART2_BASE) = f405_brr(F405_APB1_HZ, CONSOLE_BAUD);
  USART_CR1(USART2_BASE) = USART_CR1_UE | USART_CR1_TE | USART_CR1_RE | USART_CR1_RXNEIE;
  (void)USART_DR(USART2_BASE);         // QEMU asks its backend for input again on a DR read
}

void f405_console_write(const char* text) {
  for (; *text; text++) {
    while (!(USART_SR(USART2_BASE) & USART_SR_TXE)) {
    }
    USART_DR(USART2_BASE) = (uint8_t)*text;
  }
}

void board_uart_init(uint32_t baud) {
  GPIO_BSRR(GPIOA_BASE) = 1u << (DIR_PIN + 16);       // receive
  f405_pin(GPIOA_BASE, DIR_PIN, GPIO_MODE_OUTPUT, 0);
  f405_pin(GPIOA_BASE, 9, GPIO_MODE_AF, 7);
  GPIO_OTYPER(GPIOA_BASE) |= 1u << 9;                  // open drain
  GPIO_PUPDR(GPIOA_BASE) = (GPIO_PUPDR(GPIOA_BASE) & ~(3u << 18)) | 1u << 18;   // weak pull-up
  USART_CR1(USART1_BASE) = 0;
  USART_BRR(USART1_BASE) = f405_brr(F405_APB2_HZ, baud);
  USART_CR3(USART1_BASE) = USART_CR3_HDSEL;
  g_rx_head = g_rx_tail = 0;
  USART_CR1(USART1_BASE) = USART_CR1_UE | USART_CR1_TE | USART_CR1_RE | USART_CR1_RXNEIE;
  (void)USART_DR(USART1_BASE);
  NVIC_ENABLE(IRQ_USART1);
  // USART2 (the console, set up at reset) carries the sync line's records in a BOARD_HIL build;
  // its interrupt is enabled only while hil_wait sleeps
}

void board_uart_write(const uint8_t* data, size_t n) {
  int echo = !f405_emulated();        // silicon: HDSEL's receiver would hear these bytes
  if (echo) USART_CR1(USART1_BASE) &= ~USART_CR1_RE;
  GPIO_BSRR(GPIOA_BASE) = 1u << DIR_PIN;               // transmit
  for (size_t k = 0; k < n; k++) {
    while (!(USART_SR(USART1_BASE) & USART_SR_TXE)) {
    }
    USART_DR(USART1_BASE) = data[k];
  }
  for (uint32_t polls = 0; polls < TC_POLLS && !(USART_SR(USART1_BASE) & USART_SR_TC); polls++) {
  }
  GPIO_BSRR(GPIOA_BASE) = 1u << (DIR_PIN + 16);       // receive: the servo may answer now
  if (echo) USART_CR1(USART1_BASE) |= USART_CR1_RE;
  ring_sent(n);
}
