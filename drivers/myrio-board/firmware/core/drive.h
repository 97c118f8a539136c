/*
 * The board's drive loop: one tick per 1 / BOARD_LOOP_RATE_HZ.
 *
 * 1. read the encoder and the load sensor at the tick's start;
 * 2. estimate the velocity: backward difference of the encoder through a
 *    first-order low-pass at velocity_filter_hz;
 * 3. while enabled, check the velocity and position limits and the
 *    amplifier's fault line (a trip: torque zero from this tick on);
 * 4. compute the torque command for the mode (PROTOCOL.md section 11.4):
 *    the cascade is position P -> velocity PI -> torque;
 * 5. pass it through the filter slots, check the torque limit, saturate at
 *    torque_max_nm and write it to the power stage (section 9, 10).
 */
#ifndef DRIVE_H
#define DRIVE_H

#include <stdbool.h>

#include "biquad.h"
#include "protocol.h"

/* Controller settings of the board's servo loops (not in the protocol: a
 * board's own tuning, chosen for its axis). */
struct drive_tuning {
	double kp_pos_per_s;       /* position loop, (m/s) per m */
	double kv_nm_per_mps;      /* velocity loop proportional gain, N*m per (m/s) */
	double ti_s;               /* velocity loop integral time, s (0: no integral action) */
	double velocity_filter_hz; /* low-pass on the velocity estimate, Hz */
	double torque_max_nm;      /* power stage saturation, N*m */
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
	struct drive_tuning tuning;
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

void drive_init(struct drive *d, const struct drive_tuning *tuning);

/* Close the loops in `mode`: capture the hold position, clear the integrator
 * and the filter sections' state, enable the amplifier. */
void drive_enable(struct drive *d, enum run_mode mode);

/* Open the loops: torque zero, integrator cleared, amplifier disabled. */
void drive_disable(struct drive *d);

/* One loop tick with excitation value `e` (in the mode's unit; unused while
 * disabled). A trip disables the drive before the torque is written. */
void drive_step(struct drive *d, double e, struct drive_tick *out);

#endif
