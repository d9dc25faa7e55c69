// stm32f405.h: the STM32F405's registers the board layer uses, written by hand from the reference
// manual (RM0090) and the Cortex-M4 generic user guide -- only these, no vendor header.
//
// F405_REG(base, offset) is a volatile 32-bit register. The host build of the bxCAN test double
// (tests/f405/can_double.c) defines F405_CAN1_BASE and GPIOB_BASE as addresses of arrays in its
// own memory and F405_POLL() as its model's step, so the driver's register code runs unchanged.
#ifndef STM32F405_H
#define STM32F405_H

#include <stdint.h>

#define F405_REG(base, offset) (*(volatile uint32_t*)((uintptr_t)(base) + (offset)))

// a busy-wait loop's body: nothing on the chip; the test double's device model on the host
#ifndef F405_POLL
#define F405_POLL() ((void)0)
#endif

//---------------------------------- Cortex-M4 system --------------------------------------------
#define SYST_CSR F405_REG(0xE000E010u, 0x0)
#define SYST_RVR F405_REG(0xE000E010u, 0x4)
#define SYST_CVR F405_REG(0xE000E010u, 0x8)
#define SYST_ENABLE 1u
#define SYST_TICKINT 2u
#define SYST_CLKSOURCE 4u              // the processor clock (HCLK), not HCLK/8
#define NVIC_ISER(n) F405_REG(0xE000E100u, 4u * (n))
#define NVIC_ICER(n) F405_REG(0xE000E180u, 4u * (n))
#define NVIC_ENABLE(irq) (NVIC_ISER((irq) >> 5) = 1u << ((irq) & 31u))
#define NVIC_DISABLE(irq) (NVIC_ICER((irq) >> 5) = 1u << ((irq) & 31u))
#define SCB_VTOR F405_REG(0xE000ED08u, 0x0)
#define SCB_CPACR F405_REG(0xE000ED88u, 0x0)

//---------------------------------- RCC, flash interface (RM0090 7, 3.9) ------------------------
#define RCC_BASE 0x40023800u
#define RCC_CR F405_REG(RCC_BASE, 0x00)
#define RCC_PLLCFGR F405_REG(RCC_BASE, 0x04)
#define RCC_CFGR F405_REG(RCC_BASE, 0x08)
#define RCC_AHB1ENR F405_REG(RCC_BASE, 0x30)
#define RCC_APB1ENR F405_REG(RCC_BASE, 0x40)
#define RCC_APB2ENR F405_REG(RCC_BASE, 0x44)
#define RCC_CR_HSION (1u << 0)
#define RCC_CR_HSIRDY (1u << 1)
#define RCC_CR_HSEON (1u << 16)
#define RCC_CR_HSERDY (1u << 17)
#define RCC_CR_PLLON (1u << 24)
#define RCC_CR_PLLRDY (1u << 25)
#define RCC_PLLCFGR_SRC_HSE (1u << 22)
#define RCC_CFGR_SW_PLL 2u
#define RCC_CFGR_SWS_MASK (3u << 2)
#define RCC_CFGR_SWS_PLL (2u << 2)
#define RCC_CFGR_PPRE1_DIV4 (5u << 10)  // APB1 = HCLK / 4
#define RCC_CFGR_PPRE2_DIV2 (4u << 13)  // APB2 = HCLK / 2
#define RCC_AHB1ENR_GPIOA (1u << 0)
#define RCC_AHB1ENR_GPIOB (1u << 1)
#define RCC_AHB1ENR_CCMRAM (1u << 20)
#define RCC_APB1ENR_TIM2 (1u << 0)
#define RCC_APB1ENR_USART2 (1u << 17)
#define RCC_APB1ENR_USART3 (1u << 18)
#define RCC_APB1ENR_CAN1 (1u << 25)
#define RCC_APB2ENR_USART1 (1u << 4)
#define FLASH_ACR F405_REG(0x40023C00u, 0x00)
#define FLASH_ACR_5WS 5u
#define FLASH_ACR_PRFTEN (1u << 8)
#define FLASH_ACR_ICEN (1u << 9)
#define FLASH_ACR_DCEN (1u << 10)

//---------------------------------- GPIO (RM0090 8) ---------------------------------------------
#define GPIOA_BASE 0x40020000u
#ifndef GPIOB_BASE
#define GPIOB_BASE 0x40020400u         // CAN1's pins (the host test double points it at its memory)
#endif
#define GPIO_MODER(b) F405_REG(b, 0x00)
#define GPIO_OTYPER(b) F405_REG(b, 0x04)
#define GPIO_OSPEEDR(b) F405_REG(b, 0x08)
#define GPIO_PUPDR(b) F405_REG(b, 0x0C)
#define GPIO_BSRR(b) F405_REG(b, 0x18)
#define GPIO_AFRL(b) F405_REG(b, 0x20)
#define GPIO_AFRH(b) F405_REG(b, 0x24)
#define GPIO_MODE_OUTPUT 1u
#define GPIO_MODE_AF 2u
#define GPIO_PULL_UP 1u

//---------------------------------- USART (RM0090 30) -------------------------------------------
#define USART1_BASE 0x40011000u        // APB2 (84 MHz), IRQ 37, QEMU -serial #0
#define USART2_BASE 0x40004400u        // APB1 (42 MHz), IRQ 38, QEMU -serial #1
#define USART3_BASE 0x40004800u        // APB1 (42 MHz), IRQ 39, QEMU -serial #2
#define IRQ_USART1 37u
#define IRQ_USART2 38u
#define IRQ_USART3 39u
#define USART_SR(b) F405_REG(b, 0x00)
#define USART_DR(b) F405_REG(b, 0x04)
#define USART_BRR(b) F405_REG(b, 0x08)
#define USART_CR1(b) F405_REG(b, 0x0C)
#define USART_CR2(b) F405_REG(b, 0x10)
#define USART_CR3(b) F405_REG(b, 0x14)
#define USART_SR_ORE (1u << 3)
#define USART_SR_RXNE (1u << 5)
#define USART_SR_TC (1u << 6)
#define USART_SR_TXE (1u << 7)
#define USART_CR1_RE (1u << 2)
#define USART_CR1_TE (1u << 3)
#define USART_CR1_RXNEIE (1u << 5)
#define USART_CR1_UE (1u << 13)
#define USART_CR3_HDSEL (1u << 3)

//---------------------------------- TIM2 (RM0090 18): the emulated-time reference ---------------
#define TIM2_BASE 0x40000000u
#define TIM2_CR1 F405_REG(TIM2_BASE, 0x00)
#define TIM2_EGR F405_REG(TIM2_BASE, 0x14)
#define TIM2_CNT F405_REG(TIM2_BASE, 0x24)
#define TIM2_PSC F405_REG(TIM2_BASE, 0x28)
#define TIM2_ARR F405_REG(TIM2_BASE, 0x2C)
#define TIM_CR1_CEN 1u
#define TIM_EGR_UG 1u

//---------------------------------- bxCAN (RM0090 32) -------------------------------------------
#ifndef F405_CAN1_BASE
#define F405_CAN1_BASE 0x40006400u     // APB1 (42 MHz); CAN1_TX IRQ 19, RX0 20, RX1 21, SCE 22
#endif
#define CAN_MCR F405_REG(F405_CAN1_BASE, 0x000)
#define CAN_MSR F405_REG(F405_CAN1_BASE, 0x004)
#define CAN_TSR F405_REG(F405_CAN1_BASE, 0x008)
#define CAN_RF0R F405_REG(F405_CAN1_BASE, 0x00C)
#define CAN_IER F405_REG(F405_CAN1_BASE, 0x014)
#define CAN_ESR F405_REG(F405_CAN1_BASE, 0x018)
#define CAN_BTR F405_REG(F405_CAN1_BASE, 0x01C)
#define CAN_TIR(m) F405_REG(F405_CAN1_BASE, 0x180 + 0x10 * (m))
#define CAN_TDTR(m) F405_REG(F405_CAN1_BASE, 0x184 + 0x10 * (m))
#define CAN_TDLR(m) F405_REG(F405_CAN1_BASE, 0x188 + 0x10 * (m))
#define CAN_TDHR(m) F405_REG(F405_CAN1_BASE, 0x18C + 0x10 * (m))
#define CAN_RI0R F405_REG(F405_CAN1_BASE, 0x1B0)
#define CAN_RDT0R F405_REG(F405_CAN1_BASE, 0x1B4)
#define CAN_RDL0R F405_REG(F405_CAN1_BASE, 0x1B8)
#define CAN_RDH0R F405_REG(F405_CAN1_BASE, 0x1BC)
#define CAN_FMR F405_REG(F405_CAN1_BASE, 0x200)
#define CAN_FM1R F405_REG(F405_CAN1_BASE, 0x204)
#define CAN_FS1R F405_REG(F405_CAN1_BASE, 0x20C)
#define CAN_FFA1R F405_REG(F405_CAN1_BASE, 0x214)
#define CAN_FA1R F405_REG(F405_CAN1_BASE, 0x21C)
#define CAN_FR1(n) F405_REG(F405_CAN1_BASE, 0x240 + 8 * (n))
#define CAN_FR2(n) F405_REG(F405_CAN1_BASE, 0x244 + 8 * (n))
#define CAN_MCR_INRQ (1u << 0)
#define CAN_MCR_SLEEP (1u << 1)
#define CAN_MCR_TXFP (1u << 2)
#define CAN_MCR_ABOM (1u << 6)
#define CAN_MSR_INAK (1u << 0)
#define CAN_MSR_SLAK (1u << 1)
#define CAN_TSR_TME(m) (1u << (26 + (m)))
#define CAN_TSR_CODE_SHIFT 24
#define CAN_RF0R_FMP_MASK 3u
#define CAN_RF0R_FOVR (1u << 4)
#define CAN_RF0R_RFOM (1u << 5)
#define CAN_TIR_TXRQ 1u
#define CAN_IR_IDE (1u << 2)           // TIxR/RIxR: extended identifier
#define CAN_IR_RTR (1u << 1)
#define CAN_FMR_FINIT 1u
#define CAN_BTR_SILM (1u << 31)
#define CAN_BTR_LBKM (1u << 30)

#endif  // STM32F405_H
