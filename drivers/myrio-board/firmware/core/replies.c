/* The board's messages other than SAMPLES (PROTOCOL.md sections 4.7-4.15). */
#include "board_internal.h"
#include "wire.h"

#define CONTROL_PAYLOAD_MAX 240u /* fits CONTROL_FRAME_MAX once stuffed and checksummed */

static const char *const channel_table[BOARD_N_CHANNELS][2] = BOARD_CHANNEL_TABLE;

bool send_payload(struct board *b, uint8_t *payload, size_t n, size_t keep_free)
{
	uint16_t seq = (uint16_t)(b->seq + 1u); /* modulo 2^16 (section 3) */
	payload[0] = PROTOCOL_VERSION;
	put_u16(payload + 2, seq);
	if (!tx_queue_frame(&b->tx, payload, n, keep_free))
		return false;
	b->seq = seq; /* numbered only when sent */
	return true;
}

/* A control message: always queued (the reserve guarantees room). */
static void send_control(struct board *b, struct writer *w)
{
	if (w->overflow || !send_payload(b, w->buf, w->len, 0))
		b->tx.overflows++;
}

static void start(struct writer *w, uint8_t *buf, uint8_t type)
{
	w->buf = buf;
	w->cap = CONTROL_PAYLOAD_MAX;
	w->len = 0;
	w->overflow = 0;
	w_u8(w, PROTOCOL_VERSION);
	w_u8(w, type);
	w_u16(w, 0); /* seq, set when sent */
}

void reply_ack(struct board *b, uint16_t seq, uint8_t type)
{
	uint8_t buf[CONTROL_PAYLOAD_MAX];
	struct writer w;
	start(&w, buf, MSG_ACK);
	w_u16(&w, seq);
	w_u8(&w, type);
	send_control(b, &w);
}

void reply_nak(struct board *b, uint16_t seq, uint8_t type, enum error_code error, const char *detail)
{
	uint8_t buf[CONTROL_PAYLOAD_MAX];
	struct writer w;
	start(&w, buf, MSG_NAK);
	w_u16(&w, seq);
	w_u8(&w, type);
	w_u8(&w, (uint8_t)error);
	w_str(&w, detail);
	send_control(b, &w);
}

void reply_event(struct board *b, enum event_code code, uint32_t sample_index, float value, const char *message)
{
	uint8_t buf[CONTROL_PAYLOAD_MAX];
	struct writer w;
	start(&w, buf, MSG_EVENT);
	w_u8(&w, (uint8_t)code);
	w_u32(&w, sample_index);
	w_f32(&w, value);
	w_str(&w, message);
	send_control(b, &w);
}

void reply_status(struct board *b)
{
	uint8_t buf[CONTROL_PAYLOAD_MAX];
	struct writer w;
	start(&w, buf, MSG_STATUS);
	w_u8(&w, (uint8_t)b->state);
	w_u16(&w, (uint16_t)b->fault);
	w_u32(&w, fifo_level(&b->fifo));
	w_u32(&w, BOARD_EXCITATION_CAPACITY);
	w_u32(&w, b->counters.underruns);
	w_u32(&w, b->counters.dropped_blocks);
	w_u32(&w, b->run.produced);
	w_u32(&w, b->counters.limit_trips);
	w_u32(&w, b->counters.rx_corrupt + b->rx.corrupt);
	send_control(b, &w);
}

void reply_identity(struct board *b)
{
	uint8_t buf[CONTROL_PAYLOAD_MAX];
	struct writer w;
	start(&w, buf, MSG_IDENTITY);
	w_u8(&w, BOARD_PROTOCOL_VERSION);
	w_f32(&w, (float)BOARD_LOOP_RATE_HZ);
	w_f32(&w, (float)BOARD_MAX_SAMPLE_RATE_HZ);
	w_u8(&w, BOARD_FILTER_SLOTS);
	w_u32(&w, BOARD_EXCITATION_CAPACITY);
	w_str(&w, BOARD_NAME);
	w_str(&w, BOARD_FIRMWARE);
	w_u8(&w, BOARD_N_CHANNELS);
	for (unsigned i = 0; i < BOARD_N_CHANNELS; i++) {
		w_str(&w, channel_table[i][0]);
		w_str(&w, channel_table[i][1]);
	}
	send_control(b, &w);
}

void reply_filter(struct board *b, unsigned slot)
{
	const struct filter_slot *s = &b->drive.filters.slot[slot];
	uint8_t buf[CONTROL_PAYLOAD_MAX];
	struct writer w;
	start(&w, buf, MSG_FILTER);
	w_u8(&w, (uint8_t)slot);
	w_u8(&w, s->enabled ? 1 : 0);
	w_f32(&w, s->c.b0);
	w_f32(&w, s->c.b1);
	w_f32(&w, s->c.b2);
	w_f32(&w, s->c.a1);
	w_f32(&w, s->c.a2);
	send_control(b, &w);
}

void reply_loop(struct board *b)
{
	const struct loop_gains *g = &b->drive.gains;
	uint8_t buf[CONTROL_PAYLOAD_MAX];
	struct writer w;
	start(&w, buf, MSG_LOOP);
	w_f32(&w, (float)g->kv_nm_per_mps);
	w_f32(&w, (float)g->ti_s);
	w_f32(&w, (float)g->kp_pos_per_s);
	w_f32(&w, (float)g->velocity_filter_hz);
	w_f32(&w, (float)BOARD_LOOP_CURRENT_LOOP_HZ);
	w_f32(&w, (float)BOARD_LOOP_DELAY_TICKS);
	send_control(b, &w);
}
