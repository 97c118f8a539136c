/*
 * The host's requests (PROTOCOL.md sections 3-5, 9-11): decode, check,
 * act, answer. Every request but EXCITATION, IDENTIFY, STATUS_REQUEST,
 * READ_FILTER and READ_LOOP is answered by an ACK on success; a refusal is a
 * NAK with the request's seq and type.
 */
#include <math.h>

#include "board_internal.h"
#include "hal.h"
#include "text.h"
#include "wire.h"

/* One request: its header fields and its body. Only EXCITATION can be longer
 * than what was kept (`stored` < `length`, frame_rx.h). */
struct request {
	uint16_t seq;
	uint8_t type;
	const uint8_t *body;
	uint32_t stored;
	uint32_t length;
};

/* A handler returns 0 when the request was carried out, else the error code
 * of its refusal with the reason in `why`. BAD_LENGTH marks an undecodable
 * payload (counted in STATUS rx_corrupt). */
typedef enum error_code (*handler_fn)(struct board *b, const struct request *rq, struct text *why);

static enum error_code refuse(struct text *why, enum error_code code, const char *reason)
{
	text_add(why, reason);
	return code;
}

/* --- identify, status, ping ------------------------------------------------------ */

static enum error_code on_identify(struct board *b, const struct request *rq, struct text *why)
{
	(void)rq;
	(void)why;
	reply_identity(b);
	return 0;
}

static enum error_code on_status_request(struct board *b, const struct request *rq, struct text *why)
{
	(void)rq;
	(void)why;
	reply_status(b);
	return 0;
}

static enum error_code on_ping(struct board *b, const struct request *rq, struct text *why)
{
	(void)b;
	(void)rq;
	(void)why;
	return 0;
}

/* --- configure (4.2) -------------------------------------------------------------- */

/* The field layout: an unknown mode or format is undecodable (11.1: BAD_LENGTH). */
static enum error_code decode_configure(const struct request *rq, struct run_config *cfg, uint8_t *n,
					struct channel_select *ch, struct text *why)
{
	const uint8_t *p = rq->body;
	*n = p[10];
	if (rq->length < 11u + 6u * *n) {
		text_add(why, "CONFIGURE: body too short (");
		text_add_u32(why, rq->length);
		return refuse(why, ERR_BAD_LENGTH, " bytes)");
	}
	cfg->divider = get_u16(p);
	cfg->block_samples = get_u16(p + 3);
	cfg->excitation_format = p[5];
	cfg->excitation_scale = get_f32(p + 6);
	for (unsigned i = 0; i < *n; i++) {
		const uint8_t *c = p + 11 + 6 * i;
		ch[i].channel = c[0];
		ch[i].format = c[1];
		ch[i].scale = get_f32(c + 2);
		if (ch[i].format >= N_FORMATS) {
			text_add(why, "unknown format ");
			text_add_u32(why, ch[i].format);
			return ERR_BAD_LENGTH;
		}
	}
	if (p[2] >= N_MODES) {
		text_add(why, "unknown mode ");
		text_add_u32(why, p[2]);
		return ERR_BAD_LENGTH;
	}
	cfg->mode = (enum run_mode)p[2];
	if (cfg->excitation_format >= N_FORMATS) {
		text_add(why, "unknown format ");
		text_add_u32(why, cfg->excitation_format);
		return ERR_BAD_LENGTH;
	}
	return 0;
}

static enum error_code check_configure(const struct run_config *cfg, uint8_t n, const struct channel_select *ch,
				       struct text *why)
{
	if (cfg->divider == 0 || BOARD_LOOP_RATE_HZ / cfg->divider > BOARD_MAX_SAMPLE_RATE_HZ) {
		text_add(why, "sample divider ");
		text_add_u32(why, cfg->divider);
		if (cfg->divider) {
			text_add(why, " gives ");
			text_add_u32(why, (uint32_t)(BOARD_LOOP_RATE_HZ / cfg->divider + 0.5));
			text_add(why, " Hz");
		}
		return ERR_BAD_ARGUMENT;
	}
	if (cfg->block_samples < 1 || cfg->block_samples > MAX_BLOCK_SAMPLES) {
		text_add(why, "block of ");
		text_add_u32(why, cfg->block_samples);
		return refuse(why, ERR_BAD_ARGUMENT, " samples");
	}
	if (n == 0)
		return refuse(why, ERR_BAD_ARGUMENT, "channel index out of range (no channels)");
	for (unsigned i = 0; i < n; i++) {
		if (ch[i].channel >= BOARD_N_CHANNELS)
			return refuse(why, ERR_BAD_ARGUMENT, "channel index out of range");
		if (ch[i].format != FMT_F32 && !(ch[i].scale > 0.0f))
			return refuse(why, ERR_BAD_ARGUMENT, "integer channel needs a positive scale");
	}
	return 0;
}

static enum error_code on_configure(struct board *b, const struct request *rq, struct text *why)
{
	static struct channel_select ch[MAX_SELECTED_CHANNELS]; /* static: 1.5 kB off the stack */
	struct run_config cfg;
	uint8_t n;
	enum error_code err = decode_configure(rq, &cfg, &n, ch, why);
	if (err)
		return err;
	if (b->state == ST_RUNNING)
		return refuse(why, ERR_BAD_STATE, "cannot configure while running");
	err = check_configure(&cfg, n, ch, why);
	if (err)
		return err;
	cfg.valid = true;
	b->config = cfg;
	sampler_configure(&b->sampler, n, ch, cfg.block_samples);
	fifo_reset(&b->fifo); /* a new configuration starts an empty excitation stream */
	if (b->state != ST_FAULT)
		b->state = ST_CONFIGURED;
	return 0;
}

/* --- limits, start, stop, clear fault (4.3-4.5, 5, 9) ------------------------------ */

static enum error_code on_set_limits(struct board *b, const struct request *rq, struct text *why)
{
	const uint8_t *p = rq->body;
	double torque = get_f32(p), velocity = get_f32(p + 4);
	double lo = get_f32(p + 8), hi = get_f32(p + 12);
	if (!(isfinite(torque) && isfinite(velocity) && isfinite(lo) && isfinite(hi)))
		return refuse(why, ERR_BAD_ARGUMENT, "limits must be finite numbers");
	if (!(torque > 0.0 && velocity > 0.0 && lo < hi))
		return refuse(why, ERR_BAD_ARGUMENT, "limits must be positive and the window non-empty");
	b->drive.limits.torque_nm = torque;
	b->drive.limits.velocity_mps = velocity;
	b->drive.limits.position_min_m = lo;
	b->drive.limits.position_max_m = hi;
	b->limits_loaded = true;
	return 0;
}

static enum error_code on_start(struct board *b, const struct request *rq, struct text *why)
{
	if (b->state == ST_FAULT) {
		/* fault NONE in FAULT: the amplifier's fault line stopped the run (run.c) */
		text_add(why, b->fault == FAULT_NONE ? "amplifier fault" : "fault ");
		text_add(why, b->fault == FAULT_NONE ? "" : fault_name(b->fault));
		return refuse(why, ERR_FAULT_ACTIVE, " active; send CLEAR_FAULT");
	}
	if (b->state != ST_CONFIGURED) {
		text_add(why, "cannot start in state ");
		return refuse(why, ERR_BAD_STATE, state_name(b->state));
	}
	if (!b->limits_loaded)
		return refuse(why, ERR_BAD_STATE, "no safety limits loaded (send SET_LIMITS first)");
	if (hal_amplifier_fault())
		return refuse(why, ERR_BAD_STATE, "the amplifier's fault line is active");
	run_start(b, get_u32(rq->body));
	return 0;
}

static enum error_code on_stop(struct board *b, const struct request *rq, struct text *why)
{
	(void)rq; /* the reason byte is the host's own */
	(void)why;
	if (b->state == ST_RUNNING)
		run_stop(b); /* last block and EVENT STOPPED go before the ACK */
	drive_disable(&b->drive);
	return 0;
}

static enum error_code on_clear_fault(struct board *b, const struct request *rq, struct text *why)
{
	(void)rq;
	if (b->state == ST_RUNNING)
		return refuse(why, ERR_BAD_STATE, "running");
	b->fault = FAULT_NONE;
	b->state = b->config.valid ? ST_CONFIGURED : ST_IDLE;
	return 0;
}

/* --- excitation (4.6, 6) -------------------------------------------------------------- */

static double excitation_value(const uint8_t *p, uint8_t format, float scale)
{
	if (format == FMT_I16)
		return (double)(int16_t)get_u16(p) * scale;
	if (format == FMT_I32)
		return (double)(int32_t)get_u32(p) * scale;
	return get_f32(p);
}

static enum error_code on_excitation(struct board *b, const struct request *rq, struct text *why)
{
	/* before any CONFIGURE the values are read as F32 (and refused: BAD_STATE) */
	uint8_t format = b->config.valid ? b->config.excitation_format : FMT_F32;
	float scale = b->config.valid ? b->config.excitation_scale : 1.0f;
	uint32_t size = format_bytes(format);
	uint32_t first = get_u32(rq->body);
	uint32_t n = get_u16(rq->body + 4);
	uint32_t bytes = rq->length - 6u;
	if (bytes % size || bytes / size != n) {
		text_add(why, "EXCITATION announces ");
		text_add_u32(why, n);
		text_add(why, " values in ");
		text_add_u32(why, bytes);
		return refuse(why, ERR_BAD_LENGTH, " bytes");
	}
	if (b->state != ST_CONFIGURED && b->state != ST_RUNNING) {
		text_add(why, "excitation while ");
		return refuse(why, ERR_BAD_STATE, state_name(b->state));
	}
	if (first != b->fifo.written) {
		text_add(why, "excitation starts at ");
		text_add_u32(why, first);
		text_add(why, ", expected ");
		text_add_u32(why, b->fifo.written);
		return ERR_BAD_ARGUMENT;
	}
	/* A frame longer than the receive buffer holds more values than the FIFO
	 * (board_config.h): it cannot fit, whatever its values. */
	bool whole = rq->stored == rq->length;
	const uint8_t *values = rq->body + 6;
	for (uint32_t i = 0; whole && i < n; i++) {
		if (!isfinite(excitation_value(values + i * size, format, scale))) {
			text_add(why, "excitation from ");
			text_add_u32(why, first);
			return refuse(why, ERR_BAD_ARGUMENT, " holds NaN or inf");
		}
	}
	if (!whole || (uint64_t)fifo_level(&b->fifo) + n > BOARD_EXCITATION_CAPACITY) {
		text_add_u32(why, n);
		text_add(why, " samples do not fit the ");
		text_add_u32(why, BOARD_EXCITATION_CAPACITY);
		return refuse(why, ERR_BUFFER_OVERFLOW, "-sample buffer");
	}
	for (uint32_t i = 0; i < n; i++)
		fifo_push(&b->fifo, (float)excitation_value(values + i * size, format, scale));
	return 0;
}

/* --- filter slots (4.7, 4.8, 10) --------------------------------------------------------- */

static enum error_code check_slot(unsigned slot, struct text *why)
{
	if (slot < BOARD_FILTER_SLOTS)
		return 0;
	text_add(why, "filter slot ");
	text_add_u32(why, slot);
	text_add(why, " (board has ");
	text_add_u32(why, BOARD_FILTER_SLOTS);
	return refuse(why, ERR_BAD_ARGUMENT, ")");
}

static enum error_code on_write_filter(struct board *b, const struct request *rq, struct text *why)
{
	const uint8_t *p = rq->body;
	unsigned slot = p[0];
	bool enabled = p[1] != 0;
	struct biquad_coefficients c = {get_f32(p + 2), get_f32(p + 6), get_f32(p + 10), get_f32(p + 14),
					get_f32(p + 18)};
	enum error_code err = check_slot(slot, why);
	if (err)
		return err;
	if (!biquad_is_finite(&c))
		return refuse(why, ERR_BAD_ARGUMENT, "coefficients must be finite");
	if (enabled && !biquad_is_stable(&c))
		return refuse(why, ERR_BAD_ARGUMENT, "unstable coefficients refused (a pole on or outside |z| = 1)");
	filter_chain_write(&b->drive.filters, slot, &c, enabled);
	return 0;
}

static enum error_code on_read_filter(struct board *b, const struct request *rq, struct text *why)
{
	unsigned slot = rq->body[0];
	enum error_code err = check_slot(slot, why);
	if (err)
		return err;
	reply_filter(b, slot);
	return 0;
}

/* --- the loop's gains (4.15, 4.16) ------------------------------------------------------ */

static enum error_code on_read_loop(struct board *b, const struct request *rq, struct text *why)
{
	(void)rq;
	(void)why;
	reply_loop(b);
	return 0;
}

/* Taken whole or not at all, in every state. The request is handled before
 * the tick's loop step (board.c), so a running loop runs the new gains from
 * this very tick: every tick runs one set, never a mixture. */
static enum error_code on_write_loop(struct board *b, const struct request *rq, struct text *why)
{
	const uint8_t *p = rq->body;
	struct loop_gains g = {
		.kv_nm_per_mps = get_f32(p),
		.ti_s = get_f32(p + 4),
		.kp_pos_per_s = get_f32(p + 8),
		.velocity_filter_hz = get_f32(p + 12),
	};
	const char *refusal = loop_gains_refusal(&g);
	if (refusal)
		return refuse(why, ERR_BAD_ARGUMENT, refusal);
	drive_set_gains(&b->drive, &g);
	return 0;
}

/* --- dispatch --------------------------------------------------------------------------- */

struct request_kind {
	handler_fn fn;
	uint8_t min_body; /* fixed part of the body (section 4) */
	bool acked;       /* success answered by ACK */
	const char *name;
};

static const struct request_kind kinds[] = {
	[MSG_IDENTIFY] = {on_identify, 0, false, "IDENTIFY"},
	[MSG_CONFIGURE] = {on_configure, 11, true, "CONFIGURE"},
	[MSG_SET_LIMITS] = {on_set_limits, 16, true, "SET_LIMITS"},
	[MSG_START] = {on_start, 4, true, "START"},
	[MSG_STOP] = {on_stop, 1, true, "STOP"},
	[MSG_EXCITATION] = {on_excitation, 6, false, "EXCITATION"},
	[MSG_STATUS_REQUEST] = {on_status_request, 0, false, "STATUS_REQUEST"},
	[MSG_WRITE_FILTER] = {on_write_filter, FILTER_BODY_BYTES, true, "WRITE_FILTER"},
	[MSG_READ_FILTER] = {on_read_filter, 1, false, "READ_FILTER"},
	[MSG_CLEAR_FAULT] = {on_clear_fault, 0, true, "CLEAR_FAULT"},
	[MSG_PING] = {on_ping, 0, true, "PING"},
	[MSG_READ_LOOP] = {on_read_loop, 0, false, "READ_LOOP"},
	[MSG_WRITE_LOOP] = {on_write_loop, WRITE_LOOP_BODY_BYTES, true, "WRITE_LOOP"},
};

static void refuse_header(struct board *b, uint16_t seq, uint8_t type, enum error_code code, struct text *why)
{
	b->counters.rx_corrupt++;
	reply_nak(b, seq, type, code, why->s);
}

void handle_request(struct board *b, const uint8_t *payload, uint32_t stored, uint32_t length)
{
	struct text why;
	text_init(&why);
	if (length < HEADER_BYTES) {
		text_add(&why, "payload of ");
		text_add_u32(&why, length);
		text_add(&why, " bytes is shorter than the header");
		refuse_header(b, 0, length > 1 ? payload[1] : 0, ERR_BAD_LENGTH, &why);
		return;
	}
	struct request rq = {get_u16(payload + 2), payload[1], payload + HEADER_BYTES, stored - HEADER_BYTES,
			     length - HEADER_BYTES};
	if (payload[0] != PROTOCOL_VERSION) {
		text_add(&why, "protocol version ");
		text_add_u32(&why, payload[0]);
		text_add(&why, " (this board speaks 1)");
		refuse_header(b, rq.seq, rq.type, ERR_BAD_VERSION, &why);
		return;
	}
	if (rq.type >= MSG_IDENTITY && rq.type <= MSG_LOOP) {
		reply_nak(b, rq.seq, rq.type, ERR_UNKNOWN_TYPE, "not a request");
		return;
	}
	if (rq.type >= sizeof kinds / sizeof kinds[0] || kinds[rq.type].fn == NULL) {
		text_add(&why, "unknown message type ");
		text_add_u32(&why, rq.type);
		refuse_header(b, rq.seq, rq.type, ERR_UNKNOWN_TYPE, &why);
		return;
	}
	const struct request_kind *kind = &kinds[rq.type];
	enum error_code err;
	if (rq.length < kind->min_body) {
		text_add(&why, kind->name);
		text_add(&why, ": body too short (");
		text_add_u32(&why, rq.length);
		text_add(&why, " bytes)");
		err = ERR_BAD_LENGTH;
	} else {
		err = kind->fn(b, &rq, &why);
	}
	if (err == ERR_BAD_LENGTH)
		b->counters.rx_corrupt++;
	if (err)
		reply_nak(b, rq.seq, rq.type, err, why.s);
	else if (kind->acked)
		reply_ack(b, rq.seq, rq.type);
}
