/*
 * Receiving frames (PROTOCOL.md section 2): COBS-decode, check the CRC and
 * the length, byte by byte as the line delivers them.
 *
 * Decoding on the fly needs no copy of the stuffed frame: the decoded bytes
 * go through a four-byte delay line (the last four are the CRC, known only
 * at the delimiter) into the CRC and the payload buffer. A payload longer
 * than the buffer is still checked whole; only its first
 * BOARD_RX_PAYLOAD_MAX bytes are kept.
 */
#ifndef FRAME_RX_H
#define FRAME_RX_H

#include <stdbool.h>
#include <stdint.h>

#include "board_config.h"

struct frame_rx {
	uint8_t payload[BOARD_RX_PAYLOAD_MAX];
	uint32_t length;   /* payload bytes of the frame being decoded (may exceed the buffer) */
	uint32_t stuffed;  /* stuffed bytes of the current candidate */
	uint32_t crc;      /* running CRC of the payload bytes */
	uint8_t tail[4];   /* delay line: the last decoded bytes, the CRC at the end */
	uint8_t tail_n;
	uint8_t block_left;  /* data bytes left in the current COBS block */
	bool zero_pending;   /* the block that just ended stands for a zero (code < 0xFF) */
	bool discarding;     /* oversize: skip to the next delimiter */
	/* counters (section 2, step 5) */
	uint32_t frames;
	uint32_t corrupt;
	uint32_t oversize;
	uint32_t bytes_in;
};

void frame_rx_init(struct frame_rx *rx);

/* Feed one received byte. True when it completed a valid frame: its payload
 * is rx->payload, rx->length bytes long, of which frame_rx_stored() are kept. */
bool frame_rx_push(struct frame_rx *rx, uint8_t byte);

static inline uint32_t frame_rx_stored(const struct frame_rx *rx)
{
	return rx->length < BOARD_RX_PAYLOAD_MAX ? rx->length : BOARD_RX_PAYLOAD_MAX;
}

#endif
