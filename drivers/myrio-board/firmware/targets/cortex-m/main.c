/*
 * The board on a Cortex-M4 (an STM32F4 skeleton): SysTick at the loop rate,
 * the host on USART2, the core in the main loop. Interrupts only move bytes
 * and count ticks; everything else runs here.
 */
#include "board.h"
#include "hal.h"

/* At 16 MHz (no PLL) USART2 reaches 921 600 baud within 2 %; set the host's
 * [device] baudrate to match. */
#define HOST_BAUD 921600u

void hal_cortexm_init(uint32_t baud);

static struct board board;

static const struct drive_tuning tuning = {
	.kp_pos_per_s = 20.0,
	.kv_nm_per_mps = 100.0,
	.ti_s = 0.05,
	.velocity_filter_hz = 400.0,
	.torque_max_nm = 20.0,
};

int main(void)
{
	hal_cortexm_init(HOST_BAUD);
	board_init(&board, &tuning);
	for (;;) {
		hal_wait_tick();
		board_tick(&board);
	}
}
