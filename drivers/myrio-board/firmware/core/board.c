#include "board.h"

#include "board_internal.h"
#include "hal.h"

void board_init(struct board *b, double torque_max_nm)
{
	/* Power-up (section 5): IDLE, no configuration, no limits, every filter
	 * slot bypassed with identity coefficients, the loop's default gains. */
	b->state = ST_IDLE;
	b->fault = FAULT_NONE;
	b->seq = 0; /* the first message is number 1 */
	b->config.valid = false;
	b->config.divider = 1;
	b->config.mode = MODE_TORQUE;
	b->config.block_samples = 1;
	b->config.excitation_format = FMT_F32;
	b->config.excitation_scale = 1.0f;
	b->limits_loaded = false;
	drive_init(&b->drive, torque_max_nm);
	fifo_reset(&b->fifo);
	sampler_init(&b->sampler);
	b->run.n_samples = 0;
	b->run.produced = 0;
	b->run.tick_in_period = 0;
	b->counters.underruns = 0;
	b->counters.dropped_blocks = 0;
	b->counters.limit_trips = 0;
	b->counters.rx_corrupt = 0;
	b->tick = 0;
	b->last_rx_us = hal_time_us();
	frame_rx_init(&b->rx);
	tx_queue_init(&b->tx);
}

/* The host's bytes: complete frames are answered at once. Bytes are read only
 * while the transmit buffer has room for the answers; otherwise they wait in
 * the line. Any byte, even a corrupt one, feeds the watchdog (section 8). */
static void receive(struct board *b, uint64_t now_us)
{
	uint8_t chunk[RX_CHUNK];
	for (unsigned reads = 0; reads < 16; reads++) {
		if (tx_queue_free(&b->tx) < TX_CONTROL_RESERVE)
			return;
		size_t n = hal_serial_read(chunk, sizeof chunk);
		if (n == 0)
			return;
		b->last_rx_us = now_us;
		for (size_t i = 0; i < n; i++) {
			if (frame_rx_push(&b->rx, chunk[i]))
				handle_request(b, b->rx.payload, frame_rx_stored(&b->rx), b->rx.length);
		}
	}
}

/* Hand the line what it takes now. */
static void transmit(struct board *b)
{
	for (;;) {
		const uint8_t *bytes;
		size_t n = tx_queue_peek(&b->tx, &bytes);
		if (n == 0)
			return;
		size_t taken = hal_serial_write(bytes, n);
		tx_queue_consume(&b->tx, taken);
		if (taken < n)
			return;
	}
}

void board_tick(struct board *b)
{
	uint64_t now_us = hal_time_us();
	receive(b, now_us);
	if (b->state == ST_RUNNING && now_us - b->last_rx_us > BOARD_WATCHDOG_US)
		run_watchdog(b);
	if (b->state == ST_RUNNING) {
		run_step(b);
	} else {
		struct drive_tick idle; /* sensors and the velocity estimate stay current */
		drive_step(&b->drive, 0.0, &idle);
	}
	b->tick++;
	transmit(b);
}
