/*
 * Real-time pacing of the loop on a POSIX system: absolute deadlines on
 * CLOCK_MONOTONIC (clock_nanosleep), so sleeping never accumulates drift.
 *
 * Ticks shorter than `min_wake_ns` are run in fixed batches per wake-up
 * (a sped-up simulation: 4 ticks per 250 us at 16 kHz). A wake-up that comes
 * later than one whole wake period past its deadline never bursts to catch
 * up: the ticks it missed are counted in `late_ticks` and the schedule
 * restarts from now (the loop's time slips, the host sees a slower board for
 * that moment, not a burst of samples).
 */
#ifndef TICKER_H
#define TICKER_H

#include <stdint.h>
#include <time.h>

struct ticker {
	struct timespec next; /* deadline of the next wake-up */
	int64_t tick_ns;      /* wall time per tick */
	int64_t wake_ns;      /* wall time per wake-up: batch ticks */
	unsigned batch;
	unsigned in_batch;
	uint64_t wakeups;
	uint64_t late_ticks;
};

void ticker_init(struct ticker *t, double ticks_per_s, int64_t min_wake_ns);

/* Return when the next tick is due. */
void ticker_wait(struct ticker *t);

/* CLOCK_MONOTONIC, microseconds. */
uint64_t monotonic_us(void);

#endif
