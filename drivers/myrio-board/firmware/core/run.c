/*
 * A run (PROTOCOL.md sections 5-9): from START, one excitation value per
 * sample period, held for `divider` loop ticks; one row per period; blocks
 * of rows to the host; and the run's four endings (complete, STOP, a trip,
 * the watchdog).
 *
 * The sample instant (section 6): sample i is read at the first tick of its
 * period, the tick at which excitation value i starts to act. Its torques
 * are the means over the period's ticks (section 7).
 */
#include "board_internal.h"

static const char *const state_names[] = {"IDLE", "CONFIGURED", "RUNNING", "FAULT"};
static const char *const fault_names[] = {"NONE", "TORQUE_LIMIT", "VELOCITY_LIMIT", "POSITION_LIMIT", "WATCHDOG"};

const char *state_name(enum board_state state)
{
	return (unsigned)state < 4 ? state_names[state] : "?";
}

const char *fault_name(enum fault_code fault)
{
	return (unsigned)fault < 5 ? fault_names[fault] : "?";
}

void run_start(struct board *b, uint32_t n_samples)
{
	drive_enable(&b->drive, b->config.mode);
	b->run.n_samples = n_samples;
	b->run.produced = 0;
	b->run.tick_in_period = 0;
	b->run.value = 0.0;
	b->run.last_value = 0.0;
	b->run.in_underrun = false;
	b->counters.underruns = 0; /* per run; trips and corrupt frames count since power-up */
	b->counters.dropped_blocks = 0;
	sampler_start_run(&b->sampler);
	b->state = ST_RUNNING;
}

/* --- blocks --------------------------------------------------------------------------- */

/* Seal the block being filled and queue it; a block that finds no room in the
 * transmit buffer is dropped and counted (section 7), its index used all the same. */
static void send_block(struct board *b, uint16_t extra_flags)
{
	struct sampler *s = &b->sampler;
	uint16_t flags = (uint16_t)(s->pending_flags | extra_flags | (s->clipped ? FLAG_CLIPPED : 0u));
	size_t n = sampler_seal(s, 0, flags, b->fifo.read, fifo_level(&b->fifo), b->counters.underruns);
	if (n == 0 || !send_payload(b, s->block, n, TX_CONTROL_RESERVE))
		b->counters.dropped_blocks++;
	sampler_next_block(s);
}

/* --- the endings ---------------------------------------------------------------------- */

/* Torque off; excitation left in the buffer is discarded, never replayed. */
static void end_run(struct board *b, enum board_state next)
{
	drive_disable(&b->drive);
	fifo_reset(&b->fifo);
	b->state = next;
}

/* Complete or stopped: the last block, then the event (section 5). */
static void finish(struct board *b, enum event_code code, const char *message)
{
	send_block(b, FLAG_LAST);
	reply_event(b, code, b->run.produced, 0.0f, message);
	end_run(b, ST_CONFIGURED);
}

#define NO_EVENT ((enum event_code)0)

/* A trip or the watchdog: the event, then the last block flagged FAULT. An
 * amplifier fault has no version-1 fault code or event (NO_EVENT): the
 * block's FLAG_FAULT and STATUS (FAULT, fault NONE) tell the host. */
static void fault_stop(struct board *b, enum fault_code fault, enum event_code code, uint32_t index, float value,
		       const char *message)
{
	drive_disable(&b->drive);
	b->fault = fault;
	if (code != NO_EVENT)
		reply_event(b, code, index, value, message);
	send_block(b, FLAG_LAST | FLAG_FAULT);
	end_run(b, ST_FAULT);
}

void run_stop(struct board *b)
{
	finish(b, EVT_STOPPED, "stopped by host");
}

void run_watchdog(struct board *b)
{
	fault_stop(b, FAULT_WATCHDOG, EVT_WATCHDOG, b->run.produced, 0.0f, "host silent: axis stopped");
}

static void trip(struct board *b, const struct drive_tick *t)
{
	static const struct {
		enum fault_code fault;
		const char *message;
	} trips[] = {
		[TRIP_TORQUE_LIMIT] = {FAULT_TORQUE_LIMIT, "torque_limit: axis stopped, torque zero"},
		[TRIP_VELOCITY_LIMIT] = {FAULT_VELOCITY_LIMIT, "velocity_limit: axis stopped, torque zero"},
		[TRIP_POSITION_LIMIT] = {FAULT_POSITION_LIMIT, "position_limit: axis stopped, torque zero"},
		[TRIP_AMPLIFIER_FAULT] = {FAULT_NONE, "amplifier fault line: axis stopped"},
	};
	uint32_t index = b->run.produced - 1u; /* the sample of the trip, already recorded */
	if (t->trip == TRIP_AMPLIFIER_FAULT) {
		fault_stop(b, FAULT_NONE, NO_EVENT, index, 0.0f, trips[t->trip].message);
		return;
	}
	b->counters.limit_trips++;
	fault_stop(b, trips[t->trip].fault, EVT_LIMIT_TRIP, index, (float)t->trip_value, trips[t->trip].message);
}

/* --- one tick ------------------------------------------------------------------------- */

/* The value of the sample starting now: the FIFO's next, or a held one (section 6). */
static double take_excitation(struct board *b)
{
	struct run_state *r = &b->run;
	if (fifo_level(&b->fifo) > 0) {
		r->in_underrun = false;
		r->last_value = fifo_pop(&b->fifo);
		return r->last_value;
	}
	/* a set-point holds (a drop to 0 would be a step), a torque drops to 0 */
	bool hold = b->config.mode == MODE_VELOCITY || b->config.mode == MODE_POSITION;
	double held = hold ? r->last_value : 0.0;
	b->counters.underruns++;
	b->sampler.pending_flags |= FLAG_UNDERRUN;
	if (!r->in_underrun)
		reply_event(b, EVT_UNDERRUN, r->produced, (float)held,
			    hold ? "excitation buffer empty: holding the last set-point"
				 : "excitation buffer empty: holding 0");
	r->in_underrun = true;
	return held;
}

/* The period's row is complete over `ticks` loop ticks: record it. */
static void close_row(struct board *b, unsigned ticks)
{
	struct run_state *r = &b->run;
	r->row[CH_TORQUE_CMD_NM] = r->command_sum / ticks;
	r->row[CH_TORQUE_NM] = r->torque_sum / ticks;
	r->produced++;
	r->tick_in_period = 0;
	if (sampler_add_row(&b->sampler, r->row))
		send_block(b, 0);
}

void run_step(struct board *b)
{
	struct run_state *r = &b->run;
	bool first_tick = r->tick_in_period == 0;
	if (first_tick)
		r->value = take_excitation(b);
	struct drive_tick t;
	drive_step(&b->drive, r->value, &t);
	if (first_tick) { /* sample, then update: the row is the state when value i starts */
		r->row[CH_TIME_S] = (double)b->tick / BOARD_LOOP_RATE_HZ;
		r->row[CH_EXCITATION] = r->value;
		r->row[CH_POSITION_M] = t.position_m;
		r->row[CH_VELOCITY_MPS] = t.velocity_mps;
		r->row[CH_LOAD_POSITION_M] = t.load_m;
		r->command_sum = r->torque_sum = 0.0;
	}
	r->command_sum += t.command_nm;
	r->torque_sum += t.torque_nm;
	r->tick_in_period++;
	if (t.trip != TRIP_NONE) {
		/* the trip's sample is delivered, its torques averaged over the ticks it had */
		close_row(b, r->tick_in_period);
		trip(b, &t);
		return;
	}
	if (r->tick_in_period < b->config.divider)
		return;
	close_row(b, b->config.divider);
	if (r->n_samples && r->produced >= r->n_samples)
		finish(b, EVT_FINISHED, "run complete");
}
