/*
 * Filter slots (PROTOCOL.md section 10): BOARD_FILTER_SLOTS biquads in series
 * on the torque command, transposed direct form II, at the loop rate.
 *
 * Coefficients are stored as binary32, as they travel, so READ_FILTER
 * answers exactly what runs: y = b0 x + b1 x[-1] + b2 x[-2] - a1 y[-1] - a2 y[-2].
 * The sections' state is kept in double. A disabled slot passes its input
 * through; it keeps its coefficients.
 */
#ifndef BIQUAD_H
#define BIQUAD_H

#include <stdbool.h>

#include "board_config.h"

struct biquad_coefficients {
	float b0, b1, b2, a1, a2;
};

struct filter_slot {
	struct biquad_coefficients c;
	bool enabled;
	double s1, s2; /* TDF-II state */
};

struct filter_chain {
	struct filter_slot slot[BOARD_FILTER_SLOTS];
};

/* Power-up: every slot bypassed, identity coefficients. */
void filter_chain_init(struct filter_chain *chain);

/* Clear every section's state (START); coefficients and flags stay. */
void filter_chain_reset(struct filter_chain *chain);

/* Both poles strictly inside the unit circle. */
bool biquad_is_stable(const struct biquad_coefficients *c);

/* All five coefficients finite. */
bool biquad_is_finite(const struct biquad_coefficients *c);

/* Store a slot and clear its state. The caller has checked the slot number
 * and the coefficients. */
void filter_chain_write(struct filter_chain *chain, unsigned slot, const struct biquad_coefficients *c,
			bool enabled);

/* One sample through every enabled slot in order. */
double filter_chain_step(struct filter_chain *chain, double x);

#endif
