/*
 * The board: the protocol's state machine around one drive loop.
 *
 * A target calls board_init() once, then, forever,
 *
 *     hal_wait_tick();
 *     board_tick(&board);
 *
 * Each tick reads the host's bytes and answers complete requests, watches
 * the host's silence (the watchdog), runs one loop tick of the drive (and,
 * during a run, plays the excitation and records samples), and hands the
 * line what it can take of the transmit buffer.
 *
 * struct board holds every buffer: about 120 kB on a PC (a 64 kB receive
 * buffer), 72 kB on the Cortex-M skeleton. It belongs in static storage,
 * not on a stack.
 */
#ifndef BOARD_H
#define BOARD_H

#include <stdbool.h>
#include <stdint.h>

#include "board_config.h"
#include "drive.h"
#include "fifo.h"
#include "frame_rx.h"
#include "protocol.h"
#include "sampler.h"
#include "tx_queue.h"

/* What CONFIGURE set (section 4.2); the channel selection is in the sampler. */
struct run_config {
	bool valid; /* a CONFIGURE was accepted since power-up */
	uint16_t divider;
	enum run_mode mode;
	uint16_t block_samples;
	uint8_t excitation_format;
	float excitation_scale;
};

/* The run in progress (or the last one). */
struct run_state {
	uint32_t n_samples;       /* 0: until STOP, a trip or the watchdog */
	uint32_t produced;        /* samples recorded */
	uint16_t tick_in_period;  /* loop ticks of the current sample period done */
	double value;             /* excitation value of the current period */
	double last_value;        /* last fresh value played (held in an underrun) */
	bool in_underrun;         /* the last value taken was a held one */
	double row[BOARD_N_CHANNELS];   /* the current sample's row */
	double command_sum, torque_sum; /* the torques' sums over the period */
};

struct board_counters {
	uint32_t underruns;      /* this run's held samples */
	uint32_t dropped_blocks; /* this run's blocks that found no room */
	uint32_t limit_trips;    /* since power-up */
	uint32_t rx_corrupt;     /* undecodable payloads since power-up (the frame
	                            receiver counts COBS/CRC rejects) */
};

struct board {
	enum board_state state;
	enum fault_code fault;
	uint16_t seq; /* number of the board's last message */
	struct run_config config;
	bool limits_loaded;
	struct drive drive;
	struct fifo fifo;
	struct sampler sampler;
	struct run_state run;
	struct board_counters counters;
	uint64_t tick;       /* loop ticks since power-up */
	uint64_t last_rx_us; /* when the host's last byte arrived */
	struct frame_rx rx;
	struct tx_queue tx;
};

/* `torque_max_nm`: the saturation of the target's power stage, N*m. */
void board_init(struct board *b, double torque_max_nm);
void board_tick(struct board *b);

#endif
