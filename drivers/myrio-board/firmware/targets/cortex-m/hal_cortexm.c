/*
 * The hardware layer of the Cortex-M skeleton: SysTick paces the loop, USART2
 * carries the host's line. The axis is NOT PORTED: until the functions marked
 * PORT below read a real encoder and drive a real amplifier, the amplifier
 * fault line reads as active, so the board answers every request but refuses
 * START ("the amplifier's fault line is active") and never enables a drive.
 */
#include <math.h>

#include "board_config.h"
#include "hal.h"
#include "stm32f4.h"
#include "uart.h"

#define TICK_US (1000000u / (uint32_t)BOARD_LOOP_RATE_HZ)

static volatile uint64_t ticks; /* SysTick interrupts since reset */
static uint64_t ticks_done;     /* loop ticks the main loop has run */

void SysTick_Handler(void)
{
	ticks++;
}

void hal_cortexm_init(uint32_t baud)
{
	SYST_RVR = CORE_CLOCK_HZ / (uint32_t)BOARD_LOOP_RATE_HZ - 1u;
	SYST_CVR = 0;
	SYST_CSR = 0x7u; /* processor clock, interrupt, enable */
	uart_init(baud);
}

/* 64-bit tick count read consistently against the interrupt. */
static uint64_t tick_count(void)
{
	uint64_t a, b;
	do {
		a = ticks;
		b = ticks;
	} while (a != b);
	return a;
}

uint64_t hal_time_us(void)
{
	return tick_count() * TICK_US;
}

void hal_wait_tick(void)
{
	/* sleep until the next SysTick; a loop that ran late skips the ticks it
	 * missed instead of running them back to back */
	while (tick_count() <= ticks_done)
		__asm__ volatile("wfi");
	ticks_done = tick_count();
}

/* PORT: a timer in encoder mode (TIMx_CNT, both edges of A and B), times
 * metres per count. */
double hal_read_position_m(void)
{
	return 0.0;
}

/* PORT: an ADC channel on the load sensor's output; NaN when not fitted. */
double hal_read_load_position_m(void)
{
	return NAN;
}

/* PORT: a DAC (or PWM and a filter) and a +-10 V stage on the amplifier's
 * command input. */
void hal_write_torque_nm(double torque_nm)
{
	(void)torque_nm;
}

/* PORT: an ADC channel on the amplifier's current monitor. */
double hal_read_torque_nm(void)
{
	return 0.0;
}

/* PORT: a GPIO output on the amplifier's enable input. */
void hal_set_enable(bool enabled)
{
	(void)enabled;
}

/* PORT: a GPIO input on the amplifier's fault output. Active until ported. */
bool hal_amplifier_fault(void)
{
	return true;
}

size_t hal_serial_read(uint8_t *buf, size_t max)
{
	return uart_read(buf, max);
}

size_t hal_serial_write(const uint8_t *buf, size_t n)
{
	return uart_write(buf, n);
}
