/*
 * Reset and the vector table of a Cortex-M4 (STM32F4 interrupt numbers):
 * copy .data from flash, clear .bss, turn the FPU on, call main().
 */
#include <stdint.h>

#include "stm32f4.h"

extern uint32_t _sidata, _sdata, _edata, _sbss, _ebss, _estack;

int main(void);
void Reset_Handler(void);
void SysTick_Handler(void);
void USART2_IRQHandler(void);

/* Anything unexpected stops here, where a debugger finds it. */
static void Default_Handler(void)
{
	for (;;)
		;
}

void Reset_Handler(void)
{
	uint32_t *src = &_sidata;
	for (uint32_t *dst = &_sdata; dst < &_edata;)
		*dst++ = *src++;
	for (uint32_t *dst = &_sbss; dst < &_ebss;)
		*dst++ = 0;
	SCB_CPACR |= 0xFu << 20; /* CP10, CP11: full access to the FPU */
	main();
	Default_Handler();
}

#define N_VECTORS (16u + USART2_IRQ + 1u)

__attribute__((section(".isr_vector"), used)) static const uintptr_t vectors[N_VECTORS] = {
	[0] = (uintptr_t)&_estack,
	[1] = (uintptr_t)Reset_Handler,
	[2] = (uintptr_t)Default_Handler,  /* NMI */
	[3] = (uintptr_t)Default_Handler,  /* HardFault */
	[4] = (uintptr_t)Default_Handler,  /* MemManage */
	[5] = (uintptr_t)Default_Handler,  /* BusFault */
	[6] = (uintptr_t)Default_Handler,  /* UsageFault */
	[11] = (uintptr_t)Default_Handler, /* SVCall */
	[14] = (uintptr_t)Default_Handler, /* PendSV */
	[15] = (uintptr_t)SysTick_Handler,
	[16 + USART2_IRQ] = (uintptr_t)USART2_IRQHandler,
};
