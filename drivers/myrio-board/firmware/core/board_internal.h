/*
 * What the board's own modules share: board.c (the tick), requests.c (the
 * host's requests), run.c (a run: excitation, samples, its endings) and
 * replies.c (the board's messages).
 */
#ifndef BOARD_INTERNAL_H
#define BOARD_INTERNAL_H

#include <stddef.h>
#include <stdint.h>

#include "board.h"

/* Longest message the board sends other than SAMPLES, on the wire (IDENTITY,
 * about 210 bytes, is the longest; NAK and EVENT texts are cut at TEXT_MAX). */
#define CONTROL_FRAME_MAX 256u

/* Host bytes taken from the line per read. */
#define RX_CHUNK 64u

/* Transmit space kept for answers and events: sample blocks never take it,
 * and requests are read only while it is free. The bytes of one read hold at
 * most RX_CHUNK / 10 + 2 requests (a request frame is at least 10 bytes);
 * each is answered by at most two messages (STOP in a run: EVENT and ACK),
 * and a tick adds at most two events of its own. */
#define TX_CONTROL_RESERVE ((RX_CHUNK / 10u + 2u) * 2u * CONTROL_FRAME_MAX + 2u * CONTROL_FRAME_MAX)

/* replies.c */
void reply_ack(struct board *b, uint16_t seq, uint8_t type);
void reply_nak(struct board *b, uint16_t seq, uint8_t type, enum error_code error, const char *detail);
void reply_event(struct board *b, enum event_code code, uint32_t sample_index, float value, const char *message);
void reply_status(struct board *b);
void reply_identity(struct board *b);
void reply_filter(struct board *b, unsigned slot);
void reply_loop(struct board *b);
/* Number and queue a payload whose first HEADER_BYTES are left for the
 * header; false when it did not fit with `keep_free` bytes to spare. */
bool send_payload(struct board *b, uint8_t *payload, size_t n, size_t keep_free);

/* requests.c: one request payload, `length` bytes of which `stored` are in
 * `payload` (section 3). */
void handle_request(struct board *b, const uint8_t *payload, uint32_t stored, uint32_t length);

/* run.c */
void run_start(struct board *b, uint32_t n_samples);
void run_step(struct board *b);
void run_stop(struct board *b);
void run_watchdog(struct board *b);

const char *state_name(enum board_state state);
const char *fault_name(enum fault_code fault);

#endif
