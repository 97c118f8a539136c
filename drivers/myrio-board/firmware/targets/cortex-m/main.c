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

/* PORT: the amplifier's saturation, N*m (its peak current times the torque
 * constant). The loop's gains power up as board_config.h's [loop] defaults. */
#define TORQUE_MAX_NM 20.0

int main(void)
{
	hal_cortexm_init(HOST_BAUD);
	board_init(&board, TORQUE_MAX_NM);
	for (;;) {
		hal_wait_tick();
		board_tick(&board);
	}
}
