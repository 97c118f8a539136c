/*
 * The board's data: what drivers/myrio-board/driver.toml says the board is.
 *
 * Every constant names the driver.toml key (or the PROTOCOL.md section) it
 * comes from. tests/firmware/test_board_config.py reads this file and
 * driver.toml and fails when they disagree, so a change to one must be made
 * to the other.
 *
 * The buffers of the core are sized from these values; nothing is allocated
 * at run time.
 */
#ifndef BOARD_CONFIG_H
#define BOARD_CONFIG_H

#include <math.h> /* INFINITY */

/* [driver] name: what IDENTITY answers as the board name. */
#define BOARD_NAME "myrio-board"
/* [board] firmware: IDENTITY's firmware text. */
#define BOARD_FIRMWARE "hilident-board 1.0"
/* [driver] protocol_version */
#define BOARD_PROTOCOL_VERSION 1

/* [board] loop_rate_hz: drive loop and filter rate, Hz. */
#define BOARD_LOOP_RATE_HZ 4000.0
/* [board] max_sample_rate_hz: highest streamed sample rate, Hz. */
#define BOARD_MAX_SAMPLE_RATE_HZ 4000.0
/* [board] filter_slots: biquad sections in series on the torque command. */
#define BOARD_FILTER_SLOTS 4
/* [board] excitation_buffer_samples: excitation FIFO capacity, samples. */
#define BOARD_EXCITATION_CAPACITY 4096u

/*
 * [[channels]], in board order: the index is what CONFIGURE selects.
 * Units are driver.toml's `unit` strings, sent as they are in IDENTITY.
 * ([board] block_samples is the host's choice of frame size, not a board
 * constant: the board takes whatever CONFIGURE asks for, 1 to 4096.)
 */
enum board_channel {
	CH_TIME_S = 0,        /* "time_s", s */
	CH_EXCITATION,        /* "excitation", "1" (the mode's unit) */
	CH_TORQUE_CMD_NM,     /* "torque_cmd_nm", N*m, sampling = "mean" */
	CH_TORQUE_NM,         /* "torque_nm", N*m, sampling = "mean" */
	CH_POSITION_M,        /* "position_m", m */
	CH_VELOCITY_MPS,      /* "velocity_mps", m/s */
	CH_LOAD_POSITION_M,   /* "load_position_m", m, NaN out of range */
	BOARD_N_CHANNELS
};

#define BOARD_CHANNEL_TABLE                      \
	{                                        \
		{"time_s", "s"},                 \
		{"excitation", "1"},             \
		{"torque_cmd_nm", "N*m"},        \
		{"torque_nm", "N*m"},            \
		{"position_m", "m"},             \
		{"velocity_mps", "m/s"},         \
		{"load_position_m", "m"},        \
	}

/*
 * [loop]: the cascade, every parameter in the LOOP message (PROTOCOL.md
 * section 4.15). The four gains power up as these and WRITE_LOOP (4.16)
 * replaces them until power-down; the current loop and the delay are what
 * this firmware runs and are reported as they are.
 */
/* [loop] kv_nm_per_mps: velocity PI's proportional gain, N*m per (m/s). */
#define BOARD_LOOP_KV_NM_PER_MPS 100.0
/* [loop] ti_s: velocity PI's integral time, s (INFINITY: P only). */
#define BOARD_LOOP_TI_S 0.05
/* [loop] kp_pos_per_s: position loop gain, (m/s) per m. */
#define BOARD_LOOP_KP_POS_PER_S 20.0
/* [loop] velocity_filter_hz: low-pass on the velocity estimate, Hz. */
#define BOARD_LOOP_VELOCITY_FILTER_HZ 400.0
/* [loop] current_loop_hz: the board commands the amplifier's current and
 * runs no current loop of its own: INFINITY (ideal). A board on an amplifier
 * whose current loop is slow enough to matter sets its bandwidth, Hz. */
#ifndef BOARD_LOOP_CURRENT_LOOP_HZ
#define BOARD_LOOP_CURRENT_LOOP_HZ INFINITY
#endif
/* [loop] delay_ticks: the torque of a tick is written in the tick that read
 * the encoder, so no whole tick of delay. */
#define BOARD_LOOP_DELAY_TICKS 0

/*
 * Not in driver.toml: fixed by PROTOCOL.md or by this firmware.
 */

/* PROTOCOL.md section 8: a running board stops after 1 s without a byte. */
#define BOARD_WATCHDOG_US 1000000u

/* PROTOCOL.md sections 4.2 and 7: the transmit buffer. A SAMPLES frame that
 * does not fit it is never sent; its block is counted as dropped. */
#ifndef BOARD_TX_BUFFER_BYTES
#define BOARD_TX_BUFFER_BYTES 16384u
#endif

/* Largest request payload kept whole. A longer frame is still checked (COBS,
 * CRC, length) and answered; only an EXCITATION can be that long, and one
 * that long holds more values than the FIFO, so it is refused without its
 * values being read. The default keeps every frame PROTOCOL.md allows
 * (section 2: 65 536 stuffed bytes); a small microcontroller sets it to the
 * largest useful EXCITATION, 4 + 6 + 4 * BOARD_EXCITATION_CAPACITY bytes. */
#ifndef BOARD_RX_PAYLOAD_MAX
#define BOARD_RX_PAYLOAD_MAX 65536u
#endif

#endif
