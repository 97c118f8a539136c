#include "tx_queue.h"

#include "crc32.h"
#include "protocol.h"
#include "wire.h"

void tx_queue_init(struct tx_queue *q)
{
	q->head = 0;
	q->used = 0;
	q->overflows = 0;
}

/* The bytes COBS encodes: the payload, then its CRC little-endian. */
struct body {
	const uint8_t *payload;
	size_t n;
	uint8_t crc[4];
};

static inline uint8_t body_byte(const struct body *b, size_t i)
{
	return i < b->n ? b->payload[i] : b->crc[i - b->n];
}

/* Consistent Overhead Byte Stuffing (section 2). With `out` NULL only counts.
 * Each block is up to 254 non-zero bytes after a code byte (its length + 1);
 * a code below 0xFF stands for the zero that ended the block. Data that ends
 * right after a full 254-byte block gets no further empty block. Returns the
 * stuffed length (without the delimiter). */
static size_t cobs_encode(const struct body *b, struct tx_queue *out)
{
	size_t total = b->n + CRC_BYTES;
	size_t len = 0;
	size_t code_at = len++;
	bool open = true; /* a block is open: its code byte is at code_at */
	uint8_t code = 1;
	for (size_t i = 0; i < total; i++) {
		uint8_t byte = body_byte(b, i);
		if (byte == 0) {
			if (out)
				out->ring[(out->head + code_at) % BOARD_TX_BUFFER_BYTES] = code;
			code_at = len++;
			code = 1;
			continue;
		}
		if (out)
			out->ring[(out->head + len) % BOARD_TX_BUFFER_BYTES] = byte;
		len++;
		code++;
		if (code == 0xFF) {
			if (out)
				out->ring[(out->head + code_at) % BOARD_TX_BUFFER_BYTES] = code;
			open = i + 1 < total;
			if (open) {
				code_at = len++;
				code = 1;
			}
		}
	}
	if (open && out)
		out->ring[(out->head + code_at) % BOARD_TX_BUFFER_BYTES] = code;
	return len;
}

static void body_of(struct body *b, const uint8_t *payload, size_t n)
{
	b->payload = payload;
	b->n = n;
	put_u32(b->crc, crc32(payload, n));
}

bool tx_queue_frame(struct tx_queue *q, const uint8_t *payload, size_t n, size_t keep_free)
{
	struct body b;
	body_of(&b, payload, n);
	size_t wire = cobs_encode(&b, NULL) + 1;
	if (wire + keep_free > tx_queue_free(q))
		return false;
	size_t stuffed = cobs_encode(&b, q);
	q->ring[(q->head + stuffed) % BOARD_TX_BUFFER_BYTES] = 0x00;
	q->head = (q->head + wire) % BOARD_TX_BUFFER_BYTES;
	q->used += wire;
	return true;
}

size_t tx_queue_peek(const struct tx_queue *q, const uint8_t **bytes)
{
	size_t tail = (q->head + BOARD_TX_BUFFER_BYTES - q->used) % BOARD_TX_BUFFER_BYTES;
	size_t run = BOARD_TX_BUFFER_BYTES - tail;
	*bytes = q->ring + tail;
	return q->used < run ? q->used : run;
}

void tx_queue_consume(struct tx_queue *q, size_t n)
{
	q->used -= n < q->used ? n : q->used;
}
