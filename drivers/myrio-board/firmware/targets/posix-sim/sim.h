/*
 * posix-sim's hardware: the simulated gantry, its sensors and amplifier, the
 * line and the clock, as the hardware layer (hal_sim.c) sees them.
 */
#ifndef SIM_H
#define SIM_H

#include <stdbool.h>
#include <stdint.h>

#include "gantry.h"
#include "line.h"
#include "ticker.h"

struct sim {
	struct gantry gantry;
	struct line line;
	struct ticker ticker;
	double tick_s;           /* simulated seconds per loop tick */
	bool enabled;            /* amplifier enable line */
	double torque_nm;        /* torque the amplifier applies (0 while disabled) */
	double encoder_m;        /* encoder resolution, m per count */
	double torque_noise_nm;  /* standard deviation of the current monitor's noise */
	double laser_range_m;    /* the load sensor reads while |p2 - p1| <= this */
	double laser_m;          /* its resolution */
	uint64_t rng;            /* xorshift64* state */
};

extern struct sim sim;

#endif
