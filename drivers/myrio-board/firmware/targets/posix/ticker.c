#define _POSIX_C_SOURCE 200809L

#include "ticker.h"

#include <errno.h>

#define NS_PER_S 1000000000LL

static int64_t ns_of(const struct timespec *ts)
{
	return (int64_t)ts->tv_sec * NS_PER_S + ts->tv_nsec;
}

static struct timespec timespec_of(int64_t ns)
{
	struct timespec ts = {(time_t)(ns / NS_PER_S), (long)(ns % NS_PER_S)};
	return ts;
}

#ifdef __APPLE__
/* macOS has no clock_nanosleep: sleep for what is left to the deadline. */
static void sleep_until(const struct timespec *deadline)
{
	struct timespec now;
	clock_gettime(CLOCK_MONOTONIC, &now);
	int64_t left = ns_of(deadline) - ns_of(&now);
	if (left > 0) {
		struct timespec ts = timespec_of(left);
		while (nanosleep(&ts, &ts) == -1 && errno == EINTR)
			;
	}
}
#else
static void sleep_until(const struct timespec *deadline)
{
	while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, deadline, NULL) == EINTR)
		;
}
#endif

uint64_t monotonic_us(void)
{
	struct timespec now;
	clock_gettime(CLOCK_MONOTONIC, &now);
	return (uint64_t)(ns_of(&now) / 1000);
}

void ticker_init(struct ticker *t, double ticks_per_s, int64_t min_wake_ns)
{
	t->tick_ns = (int64_t)(NS_PER_S / ticks_per_s + 0.5);
	if (t->tick_ns < 1)
		t->tick_ns = 1;
	t->batch = t->tick_ns >= min_wake_ns ? 1u : (unsigned)((min_wake_ns + t->tick_ns - 1) / t->tick_ns);
	t->wake_ns = t->tick_ns * (int64_t)t->batch;
	t->in_batch = 0;
	t->wakeups = 0;
	t->late_ticks = 0;
	clock_gettime(CLOCK_MONOTONIC, &t->next);
}

void ticker_wait(struct ticker *t)
{
	if (++t->in_batch < t->batch)
		return;
	t->in_batch = 0;
	int64_t deadline = ns_of(&t->next) + t->wake_ns;
	t->next = timespec_of(deadline);
	sleep_until(&t->next);
	t->wakeups++;
	struct timespec now;
	clock_gettime(CLOCK_MONOTONIC, &now);
	int64_t late = ns_of(&now) - deadline;
	if (late > t->wake_ns) {
		/* the slots that went by are skipped, not run back to back */
		t->late_ticks += (uint64_t)(late / t->tick_ns);
		t->next = now;
	}
}
