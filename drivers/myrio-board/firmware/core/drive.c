#include "drive.h"

#include <math.h>
#include <stddef.h>

#include "board_config.h"
#include "hal.h"

#define LOOP_PERIOD_S (1.0 / BOARD_LOOP_RATE_HZ)

const char *loop_gains_refusal(const struct loop_gains *g)
{
	if (!(isfinite(g->kv_nm_per_mps) && g->kv_nm_per_mps > 0.0))
		return "kv_nm_per_mps must be finite and > 0";
	if (!(g->ti_s > 0.0)) /* +inf passes: a P controller */
		return "ti_s must be > 0 (inf: P only)";
	if (!(isfinite(g->kp_pos_per_s) && g->kp_pos_per_s > 0.0))
		return "kp_pos_per_s must be finite and > 0";
	if (!(isfinite(g->velocity_filter_hz) && g->velocity_filter_hz > 0.0))
		return "velocity_filter_hz must be finite and > 0";
	return NULL;
}

void drive_set_gains(struct drive *d, const struct loop_gains *g)
{
	const double pi = 3.14159265358979323846;
	d->gains = *g;
	d->alpha = 1.0 - exp(-2.0 * pi * g->velocity_filter_hz * LOOP_PERIOD_S);
	d->ki_per_tick = isinf(g->ti_s) ? 0.0 : g->kv_nm_per_mps * LOOP_PERIOD_S / g->ti_s;
}

void drive_init(struct drive *d, double torque_max_nm)
{
	const struct loop_gains power_up = {
		.kv_nm_per_mps = BOARD_LOOP_KV_NM_PER_MPS,
		.ti_s = BOARD_LOOP_TI_S,
		.kp_pos_per_s = BOARD_LOOP_KP_POS_PER_S,
		.velocity_filter_hz = BOARD_LOOP_VELOCITY_FILTER_HZ,
	};
	drive_set_gains(d, &power_up);
	d->torque_max_nm = torque_max_nm;
	/* No limits until SET_LIMITS: the board refuses START until then. */
	d->limits.torque_nm = INFINITY;
	d->limits.velocity_mps = INFINITY;
	d->limits.position_min_m = -INFINITY;
	d->limits.position_max_m = INFINITY;
	filter_chain_init(&d->filters);
	d->mode = MODE_TORQUE;
	d->enabled = false;
	d->hold_m = 0.0;
	d->integral = 0.0;
	d->velocity = 0.0;
	d->last_position_m = hal_read_position_m();
	hal_set_enable(false);
	hal_write_torque_nm(0.0);
}

void drive_enable(struct drive *d, enum run_mode mode)
{
	d->mode = mode;
	d->hold_m = hal_read_position_m();
	d->integral = 0.0;
	filter_chain_reset(&d->filters);
	d->enabled = true;
	hal_set_enable(true);
}

void drive_disable(struct drive *d)
{
	d->enabled = false;
	d->integral = 0.0;
	hal_write_torque_nm(0.0);
	hal_set_enable(false);
}

/* The velocity error the PI acts on, or 0 in torque mode. */
static double velocity_error(const struct drive *d, double e, double position)
{
	switch (d->mode) {
	case MODE_TORQUE_INJECTION:
		return d->gains.kp_pos_per_s * (d->hold_m - position) - d->velocity;
	case MODE_VELOCITY:
		return e - d->velocity;
	case MODE_POSITION:
		return d->gains.kp_pos_per_s * (d->hold_m + e - position) - d->velocity;
	default:
		return 0.0;
	}
}

/* Controller output plus injection, before the filter slots. */
static double controller(struct drive *d, double e, double position)
{
	if (d->mode == MODE_TORQUE)
		return e;
	double verr = velocity_error(d, e, position);
	double tmax = d->torque_max_nm;
	d->integral += d->ki_per_tick * verr;
	/* the integrator cannot wind up beyond what the power stage delivers */
	if (d->integral > tmax)
		d->integral = tmax;
	else if (d->integral < -tmax)
		d->integral = -tmax;
	double cmd = d->gains.kv_nm_per_mps * verr + d->integral;
	if (d->mode == MODE_TORQUE_INJECTION)
		cmd += e;
	return cmd;
}

/* Limits checked before the controller runs (section 9). */
static enum drive_trip check_state(const struct drive *d, double position, double *value)
{
	if (hal_amplifier_fault()) {
		*value = 0.0;
		return TRIP_AMPLIFIER_FAULT;
	}
	if (fabs(d->velocity) > d->limits.velocity_mps) {
		*value = d->velocity;
		return TRIP_VELOCITY_LIMIT;
	}
	if (position < d->limits.position_min_m || position > d->limits.position_max_m) {
		*value = position;
		return TRIP_POSITION_LIMIT;
	}
	return TRIP_NONE;
}

static double saturate(double x, double limit)
{
	return x > limit ? limit : (x < -limit ? -limit : x);
}

void drive_step(struct drive *d, double e, struct drive_tick *out)
{
	double position = hal_read_position_m();
	d->velocity += d->alpha * ((position - d->last_position_m) / LOOP_PERIOD_S - d->velocity);
	d->last_position_m = position;
	out->position_m = position;
	out->velocity_mps = d->velocity;
	out->load_m = hal_read_load_position_m();
	out->command_nm = 0.0;
	out->trip = TRIP_NONE;
	out->trip_value = 0.0;

	double applied = 0.0;
	if (d->enabled) {
		out->trip = check_state(d, position, &out->trip_value);
		if (out->trip == TRIP_NONE) {
			out->command_nm = controller(d, e, position);
			double filtered = filter_chain_step(&d->filters, out->command_nm);
			if (fabs(filtered) > d->limits.torque_nm) { /* before the power stage's saturation */
				out->trip = TRIP_TORQUE_LIMIT;
				out->trip_value = filtered;
			} else {
				applied = saturate(filtered, d->torque_max_nm);
			}
		}
		if (out->trip != TRIP_NONE)
			drive_disable(d);
	}
	if (isnan(applied))
		applied = 0.0; /* never command NaN */
	hal_write_torque_nm(applied);
	out->torque_nm = hal_read_torque_nm();
}
