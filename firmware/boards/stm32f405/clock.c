// clock.c: the STM32F405's clock tree, the control clock (SysTick) and the emulated-time reference.
//
// The clock tree (RM0090 6.3): SYSCLK = PLL = f_in / M * N / P, the 48 MHz domain = f_in / M * N / Q.
//   HSE, an 8 MHz crystal (Olimex H405, STM32F4DISCOVERY, Netduino Plus 2):
//     M = 4:  8 MHz / 4   =   2 MHz at the PLL input (1..2 MHz allowed; 2 MHz has the least jitter)
//     N = 168: 2 MHz x 168 = 336 MHz VCO (100..432 MHz allowed)
//     P = 2:  336 / 2     = 168 MHz SYSCLK = HCLK (AHB /1), the core and SysTick
//     Q = 7:  336 / 7     =  48 MHz for USB OTG / SDIO
//   HSI, the 16 MHz internal RC (no crystal, or it does not start): M = 8, then the same N, P, Q.
//   APB1 = HCLK / 4 = 42 MHz (USART2, bxCAN; its timers 84 MHz), APB2 = HCLK / 2 = 84 MHz (USART1).
//   Flash: 5 wait states at 168 MHz and 2.7-3.6 V (RM0090 table 10), prefetch and both caches on;
//   set before the switch. The regulator's scale 1 (PWR_CR.VOS) is the F405's reset value.
// Every ready-flag wait is bounded (CLOCK_POLLS polls: ~50 ms at the 16 MHz the chip starts on,
// longer than an 8 MHz crystal's start-up, which ST's HAL bounds at 100 ms... of which a good
// crystal takes 2 ms). Under QEMU the RCC is not modelled and reads 0: the waits are skipped
// (F405_CLOCK_EMULATED; QEMU's core clock is 168 MHz whatever is programmed). On silicon a crystal
// that does not start falls back to HSI with the same clocks; a PLL that does not lock leaves the
// chip on HSI 16 MHz and start-up stops with the set-up fault (16) on the console.
#include "board.h"
#include "f405.h"
#include "stm32f405.h"

#define CLOCK_POLLS 200000u
#define PLL_HSE (4u | 168u << 6 | 0u << 16 | RCC_PLLCFGR_SRC_HSE | 7u << 24)   // M, N, P=/2, Q
#define PLL_HSI (8u | 168u << 6 | 0u << 16 | 7u << 24)
#define QEMU_TIM2_HZ 1000000000u       // QEMU 7.2's TIM2-5 count at 1 GHz (stm32f405_soc.c)
#define TIM2_HZ 84000000u              // silicon: APB1 x 2
// TIM2 / 1000: 1 us a count under QEMU (84 kHz on silicon). QEMU counts TIM2 even with CEN clear
// and schedules its overflow: at 1 GHz that was every 4.3 s of emulated time, which the idle core
// in hil_wait jumped to again and again (-icount sleep=off); at 1 MHz it is 72 minutes away.
#define REF_PRESCALER 1000u

static int g_emulated;

int f405_emulated(void) {
  return g_emulated;
}

// wait until (reg & mask) == want, at most CLOCK_POLLS polls; 1 when it came
static int wait_bits(volatile uint32_t* reg, uint32_t mask, uint32_t want) {
  for (uint32_t n = 0; n < CLOCK_POLLS; n++)
    if ((*reg & mask) == want) return 1;
  return 0;
}

int f405_clock_init(void) {
  g_emulated = RCC_CR == 0;         // silicon: HSION and HSIRDY are set whenever the chip runs
  FLASH_ACR = FLASH_ACR_5WS | FLASH_ACR_PRFTEN | FLASH_ACR_ICEN | FLASH_ACR_DCEN;
  RCC_CFGR = RCC_CFGR_PPRE1_DIV4 | RCC_CFGR_PPRE2_DIV2;    // still on HSI: SW = 0
  RCC_CR |= RCC_CR_HSEON;
  int hse = g_emulated || wait_bits(&RCC_CR, RCC_CR_HSERDY, RCC_CR_HSERDY);
  if (!hse) RCC_CR &= ~RCC_CR_HSEON;
  RCC_PLLCFGR = hse ? PLL_HSE : PLL_HSI;
  RCC_CR |= RCC_CR_PLLON;
  if (!g_emulated && !wait_bits(&RCC_CR, RCC_CR_PLLRDY, RCC_CR_PLLRDY)) return F405_CLOCK_FAILED;
  RCC_CFGR = RCC_CFGR_PPRE1_DIV4 | RCC_CFGR_PPRE2_DIV2 | RCC_CFGR_SW_PLL;
  if (!g_emulated && !wait_bits(&RCC_CFGR, RCC_CFGR_SWS_MASK, RCC_CFGR_SWS_PLL)) return F405_CLOCK_FAILED;
  // the peripherals' clocks: GPIOA/B, CCM RAM, USART1 (APB2), USART2, TIM2, CAN1 (APB1)
  RCC_AHB1ENR |= RCC_AHB1ENR_GPIOA | RCC_AHB1ENR_GPIOB | RCC_AHB1ENR_CCMRAM;
  RCC_APB1ENR |= RCC_APB1ENR_TIM2 | RCC_APB1ENR_USART2 | RCC_APB1ENR_CAN1;
  RCC_APB2ENR |= RCC_APB2ENR_USART1;
  (void)RCC_APB2ENR;                // RM0090 errata 2.1.13: a read before the peripheral's first access
  return g_emulated ? F405_CLOCK_EMULATED : hse ? F405_CLOCK_HSE : F405_CLOCK_HSI;
}

//---------------------------------- the control clock: SysTick ---------------------------------
// The same as the MPS2 boards' (firmware/mcu/board_io.c) at BOARD_CPU_HZ = 168 MHz: 168,000
// counts a 1 ms period, within SysTick's 24 bits up to 99 ms.

#include "board_systick.h"

static uint32_t g_ref_mark;            // TIM2 at the last release
static uint64_t g_ref_counts;          // TIM2 counts while the clock ran

void board_clock_start(uint32_t period) {
  systick_start(period);
  TIM2_PSC = REF_PRESCALER - 1u;
  TIM2_ARR = 0xFFFFFFFFu;
  TIM2_EGR = TIM_EGR_UG;
  TIM2_CR1 = TIM_CR1_CEN;
  g_ref_counts = 0;
  g_ref_mark = TIM2_CNT;
}

void board_tick_begin(void) {}

// Holding the clock while the bus answers is for emulation alone (board.h: the simulated bus
// answers in no emulated time): on silicon the servos' replies take real time, and SysTick runs on
// through them, so the build for a board (no BOARD_HIL) leaves it running.
// QEMU's TIM2 counts on while CEN is clear, so the reference adds up the runs between release
// and hold itself (a uint32 difference: each run is far shorter than 2^32 counts)
void board_clock_hold(void) {
#ifdef BOARD_HIL
  SYST_CSR &= ~SYST_ENABLE;
#endif
  g_ref_counts += TIM2_CNT - g_ref_mark;
}

void board_clock_release(void) {
  g_ref_mark = TIM2_CNT;
#ifdef BOARD_HIL
  SYST_CSR |= SYST_ENABLE;
#endif
}

void board_clock_report(void) {
  if (g_period == 0) return;        // the clock never started (a fault in the set-up)
  board_clock_hold();
  board_write("servodyn-board: clock ticks=");
  board_write_int((long)g_ticks);
  board_write(" period=");
  board_write_int((long)g_period);
  board_write(" cpu_hz=");
  board_write_int((long)BOARD_CPU_HZ);
  board_write(" ref_us=");
  board_write_int((long)(g_ref_counts * 1000000u * REF_PRESCALER / (g_emulated ? QEMU_TIM2_HZ : TIM2_HZ)));
  board_write("\n");
}
