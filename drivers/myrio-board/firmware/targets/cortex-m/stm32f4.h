/*
 * The few registers the skeleton touches, for an STM32F4 (reference manual
 * RM0390 / RM0090) and the Cortex-M4 core. A port to another part replaces
 * this file and uart.c; the core does not change.
 */
#ifndef STM32F4_H
#define STM32F4_H

#include <stdint.h>

#define REG(addr) (*(volatile uint32_t *)(addr))

/* Cortex-M4 core */
#define SYST_CSR REG(0xE000E010u)
#define SYST_RVR REG(0xE000E014u)
#define SYST_CVR REG(0xE000E018u)
#define NVIC_ISER(n) REG(0xE000E100u + 4u * (n))
#define SCB_CPACR REG(0xE000ED88u)

/* Reset and clock control */
#define RCC_AHB1ENR REG(0x40023830u)
#define RCC_APB1ENR REG(0x40023840u)
#define RCC_AHB1ENR_GPIOAEN (1u << 0)
#define RCC_APB1ENR_USART2EN (1u << 17)

/* GPIO port A: PA2 = USART2 TX, PA3 = USART2 RX (alternate function 7) */
#define GPIOA_MODER REG(0x40020000u)
#define GPIOA_AFRL REG(0x40020020u)

/* USART2 */
#define USART2_SR REG(0x40004400u)
#define USART2_DR REG(0x40004404u)
#define USART2_BRR REG(0x40004408u)
#define USART2_CR1 REG(0x4000440Cu)
#define USART_SR_RXNE (1u << 5)
#define USART_SR_TXE (1u << 7)
#define USART_SR_ORE (1u << 3)
#define USART_CR1_UE (1u << 13)
#define USART_CR1_TXEIE (1u << 7)
#define USART_CR1_RXNEIE (1u << 5)
#define USART_CR1_TE (1u << 3)
#define USART_CR1_RE (1u << 2)
#define USART2_IRQ 38u

/* The clock after reset: the 16 MHz internal oscillator, no PLL. A real
 * board sets up its PLL (and these values) for higher baud rates. */
#define CORE_CLOCK_HZ 16000000u
#define APB1_CLOCK_HZ 16000000u

#endif
