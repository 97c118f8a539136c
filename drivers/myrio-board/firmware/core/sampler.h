/*
 * Sample rows into SAMPLES blocks (PROTOCOL.md sections 4.12 and 7).
 *
 * A row holds one value per board channel; the sampler keeps the channels
 * CONFIGURE selected, each encoded in its format, straight into the payload
 * of the block being filled (after room for the block's header). A block
 * whose rows do not fit that buffer could never be sent: its rows are not
 * kept and the block is counted as dropped when it is due.
 */
#ifndef SAMPLER_H
#define SAMPLER_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "board_config.h"
#include "protocol.h"

#define SAMPLES_PAYLOAD_HEAD (HEADER_BYTES + SAMPLES_HEAD_BYTES)
#define MAX_SELECTED_CHANNELS 255 /* CONFIGURE n_channels is a u8 */

struct channel_select {
	uint8_t channel; /* index into the board's channel list */
	uint8_t format;  /* enum value_format */
	float scale;     /* SI units per count, integer formats */
};

struct sampler {
	uint8_t n_channels;
	struct channel_select ch[MAX_SELECTED_CHANNELS];
	size_t row_bytes;
	uint16_t block_samples;

	uint8_t block[BOARD_TX_BUFFER_BYTES]; /* payload of the block being filled */
	uint16_t rows;
	bool overflowed;        /* rows did not fit: the block cannot be sent */
	bool clipped;           /* a value was saturated to its integer format */
	uint16_t pending_flags; /* FLAG_UNDERRUN since the last block */
	uint32_t first_sample;  /* run index of the block's first row */
	uint32_t block_index;   /* blocks produced since power-up, sent or dropped */
};

void sampler_init(struct sampler *s);

/* Take a configuration's channel selection and block size (already checked). */
void sampler_configure(struct sampler *s, uint8_t n_channels, const struct channel_select *ch,
		       uint16_t block_samples);

/* A run starts: an empty block from sample 0. */
void sampler_start_run(struct sampler *s);

/* Append one row (values indexed by enum board_channel); true when the
 * block now holds block_samples rows. */
bool sampler_add_row(struct sampler *s, const double row[BOARD_N_CHANNELS]);

/* Write the block's header (PROTOCOL.md 4.12) in front of its rows; returns
 * the payload length, or 0 when the block's rows were not kept. */
size_t sampler_seal(struct sampler *s, uint16_t seq, uint16_t flags, uint32_t consumed, uint32_t level,
		    uint32_t underruns);

/* The sealed block is gone (sent or dropped): start the next one. */
void sampler_next_block(struct sampler *s);

#endif
