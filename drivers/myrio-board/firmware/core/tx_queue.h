/*
 * The transmit buffer: whole frames, COBS(payload + CRC) + 0x00 (PROTOCOL.md
 * section 2), waiting for the line.
 *
 * A frame is queued whole or not at all. Sample blocks are queued only when
 * they leave `keep_free` bytes for the answers and events that must never
 * be dropped (section 7); the board stops reading requests while less than
 * that is free, so those always fit.
 */
#ifndef TX_QUEUE_H
#define TX_QUEUE_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "board_config.h"

struct tx_queue {
	uint8_t ring[BOARD_TX_BUFFER_BYTES];
	size_t head; /* next byte to write */
	size_t used; /* bytes waiting for the line */
	uint32_t overflows; /* answers that found no room (never expected) */
};

void tx_queue_init(struct tx_queue *q);

static inline size_t tx_queue_free(const struct tx_queue *q)
{
	return BOARD_TX_BUFFER_BYTES - q->used;
}

/* Queue `payload` as one frame if at least `keep_free` bytes stay free
 * afterwards; false (nothing queued) otherwise. */
bool tx_queue_frame(struct tx_queue *q, const uint8_t *payload, size_t n, size_t keep_free);

/* The oldest waiting bytes, as one contiguous run; its length (0: none). */
size_t tx_queue_peek(const struct tx_queue *q, const uint8_t **bytes);

/* The line took `n` bytes of the run tx_queue_peek() gave. */
void tx_queue_consume(struct tx_queue *q, size_t n);

#endif
