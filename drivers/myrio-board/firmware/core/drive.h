/*
 * The board's drive loop: one tick per 1 / BOARD_LOOP_RATE_HZ.
 *
 * 1. read the encoder and the load sensor at the tick's start;
 * 2. estimate the velocity: backward difference of the encoder through a
 *    first-order low-pass at velocity_filter_hz;
 * 3. while enabled, check the velocity and position limits and the
 *    amplifier's fault line (a trip: torque zero from this tick on);
 * 4. compute the torque command for the mode (PROTOCOL.md section 11.4):
 *    the cascade is position P -> velocity PI -> torque, the integrator
 *    adding its increment before the output;
 * 5. pass it through the filter slots, check the torque limit, saturate at
 *    torque_max_nm and write it to the power stage (section 9, 10), in the
 *    tick that read the encoder: no delay, and no current loop of its own
 *    (the amplifier's is BOARD_LOOP_CURRENT_LOOP_HZ).
 *
 * That is hilident.control.Cascade's model exactly, with the parameters LOOP
 * reports (PROTOCOL.md section 4.15).
 */
#ifndef DRIVE_H
#define DRIVE_H

#include <stdbool.h>

#include "biquad.h"
#include "protocol.h"

/* The cascade's gains: what LOOP reports and WRITE_LOOP sets (PROTOCOL.md
 * sections 4.15, 4.16). They power up as board_config.h's [loop] defaults. */
struct loop_gains {
	double kv_nm_per_mps;      /* velocity loop proportional gain, N*m per (m/s) */
	double ti_s;               /* velocity loop integral time, s (INFINITY: P only) */
	double kp_pos_per_s;       /* position loop, (m/s) per m */
	double velocity_filter_hz; /* low-pass on the velocity estimate, Hz */
};

/* Why the drive stopped itself in a tick. */
enum drive_trip {
	TRIP_NONE = 0,
	TRIP_TORQUE_LIMIT,
	TRIP_VELOCITY_LIMIT,
	TRIP_POSITION_LIMIT,
	TRIP_AMPLIFIER_FAULT,
};

struct drive_limits {
	double torque_nm;
	double velocity_mps;
	double position_min_m;
	double position_max_m;
};

/* What one tick measured and did. */
struct drive_tick {
	double position_m;     /* encoder, at the tick's start */
	double velocity_mps;   /* the estimate after this tick's reading */
	double load_m;         /* load sensor, NaN out of range */
	double command_nm;     /* controller output plus injection, before the filter slots */
	double torque_nm;      /* measured torque over the tick */
	enum drive_trip trip;  /* this tick's trip, if any */
	double trip_value;     /* the offending torque (N*m), velocity (m/s) or position (m) */
};

struct drive {
	struct loop_gains gains;
	double torque_max_nm; /* power stage saturation, N*m (the target's amplifier) */
	struct drive_limits limits;
	struct filter_chain filters;
	enum run_mode mode;
	bool enabled;
	double alpha;      /* velocity low-pass gain per tick */
	double ki_per_tick;  /* integral gain per tick, N*m per (m/s) */
	double hold_m;     /* position captured at enable */
	double integral;   /* velocity PI's integrator, N*m */
	double velocity;   /* estimate, m/s */
	double last_position_m;
};

/* Power-up: the [loop] defaults of board_config.h, no limits, the slots
 * bypassed, the amplifier disabled. */
void drive_init(struct drive *d, double torque_max_nm);

/* NULL when the loop can run the gains `g`, else why not (PROTOCOL.md
 * section 4.16: a NaN, a gain or cut-off not finite and > 0, an integral
 * time not > 0). */
const char *loop_gains_refusal(const struct loop_gains *g);

/* Run the gains `g` (which loop_gains_refusal() accepted) from the next tick
 * on, all four at once; the integrator, the velocity estimate and the filter
 * sections carry on. */
void drive_set_gains(struct drive *d, const struct loop_gains *g);

/* Close the loops in `mode`: capture the hold position, clear the integrator
 * and the filter sections' state, enable the amplifier. */
void drive_enable(struct drive *d, enum run_mode mode);

/* Open the loops: torque zero, integrator cleared, amplifier disabled. */
void drive_disable(struct drive *d);

/* One loop tick with excitation value `e` (in the mode's unit; unused while
 * disabled). A trip disables the drive before the torque is written. */
void drive_step(struct drive *d, double e, struct drive_tick *out);

#endif
