#include "frame_rx.h"

#include "crc32.h"
#include "protocol.h"
#include "wire.h"

static void start_candidate(struct frame_rx *rx)
{
	rx->length = 0;
	rx->stuffed = 0;
	rx->crc = CRC32_INIT;
	rx->tail_n = 0;
	rx->block_left = 0;
	rx->zero_pending = false;
}

void frame_rx_init(struct frame_rx *rx)
{
	start_candidate(rx);
	rx->discarding = false;
	rx->frames = rx->corrupt = rx->oversize = rx->bytes_in = 0;
}

/* One decoded byte: the oldest byte of the delay line is payload. */
static void emit(struct frame_rx *rx, uint8_t byte)
{
	if (rx->tail_n < 4) {
		rx->tail[rx->tail_n++] = byte;
		return;
	}
	uint8_t out = rx->tail[0];
	rx->tail[0] = rx->tail[1];
	rx->tail[1] = rx->tail[2];
	rx->tail[2] = rx->tail[3];
	rx->tail[3] = byte;
	rx->crc = crc32_byte(rx->crc, out);
	if (rx->length < BOARD_RX_PAYLOAD_MAX)
		rx->payload[rx->length] = out;
	rx->length++;
}

/* The delimiter ended a non-empty candidate: is it a frame? */
static bool end_candidate(struct frame_rx *rx)
{
	/* a COBS block cut short, or a body of 4 bytes or fewer (no payload) */
	bool ok = rx->block_left == 0 && rx->tail_n == 4 && rx->length >= 1;
	if (ok)
		ok = get_u32(rx->tail) == crc32_final(rx->crc);
	if (ok)
		rx->frames++;
	else
		rx->corrupt++;
	return ok;
}

bool frame_rx_push(struct frame_rx *rx, uint8_t byte)
{
	rx->bytes_in++;
	if (byte == 0x00) {
		bool was_discarding = rx->discarding;
		bool empty = rx->stuffed == 0;
		bool ok = false;
		rx->discarding = false;
		if (was_discarding) {
			if (!empty)
				rx->corrupt++; /* the rest of an oversize run is one corrupt candidate */
		} else if (!empty) {
			ok = end_candidate(rx);
		} /* back-to-back delimiters are idle filler: not counted */
		if (!ok)
			start_candidate(rx);
		else
			rx->stuffed = 0; /* the payload stays readable until the next byte */
		return ok;
	}
	if (rx->stuffed == 0 && rx->length != 0)
		start_candidate(rx); /* the previous frame's payload was handed over */
	rx->stuffed++;
	if (rx->discarding)
		return false;
	if (rx->stuffed > MAX_FRAME_BYTES) {
		/* more than 65 536 bytes without a delimiter: drop what is held */
		rx->oversize++;
		start_candidate(rx);
		rx->discarding = true;
		return false;
	}
	if (rx->block_left == 0) { /* a code byte */
		if (rx->zero_pending)
			emit(rx, 0x00);
		rx->block_left = (uint8_t)(byte - 1);
		rx->zero_pending = byte != 0xFF;
	} else {
		emit(rx, byte);
		rx->block_left--;
	}
	return false;
}
