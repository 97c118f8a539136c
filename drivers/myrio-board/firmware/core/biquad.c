#include "biquad.h"

#include <math.h>

static const struct biquad_coefficients identity = {1.0f, 0.0f, 0.0f, 0.0f, 0.0f};

void filter_chain_init(struct filter_chain *chain)
{
	for (unsigned i = 0; i < BOARD_FILTER_SLOTS; i++)
		filter_chain_write(chain, i, &identity, false);
}

void filter_chain_reset(struct filter_chain *chain)
{
	for (unsigned i = 0; i < BOARD_FILTER_SLOTS; i++)
		chain->slot[i].s1 = chain->slot[i].s2 = 0.0;
}

bool biquad_is_finite(const struct biquad_coefficients *c)
{
	return isfinite(c->b0) && isfinite(c->b1) && isfinite(c->b2) && isfinite(c->a1) && isfinite(c->a2);
}

bool biquad_is_stable(const struct biquad_coefficients *c)
{
	/* Jury's test for z^2 + a1 z + a2: both roots inside |z| < 1 exactly when
	 * |a2| < 1 and |a1| < 1 + a2. Evaluated in double on the stored binary32
	 * values, which are exact there: a2 = 1 - 1e-9 rounds to 1.0f and fails. */
	double a1 = c->a1, a2 = c->a2;
	return fabs(a2) < 1.0 && fabs(a1) < 1.0 + a2;
}

void filter_chain_write(struct filter_chain *chain, unsigned slot, const struct biquad_coefficients *c,
			bool enabled)
{
	struct filter_slot *s = &chain->slot[slot];
	s->c = *c;
	s->enabled = enabled;
	s->s1 = s->s2 = 0.0;
}

double filter_chain_step(struct filter_chain *chain, double x)
{
	for (unsigned i = 0; i < BOARD_FILTER_SLOTS; i++) {
		struct filter_slot *s = &chain->slot[i];
		if (!s->enabled)
			continue;
		double y = s->c.b0 * x + s->s1;
		s->s1 = s->c.b1 * x - s->c.a1 * y + s->s2;
		s->s2 = s->c.b2 * x - s->c.a2 * y;
		x = y;
	}
	return x;
}
