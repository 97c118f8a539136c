/*
 * The excitation FIFO (PROTOCOL.md section 6): one stream of values per
 * configuration, indexed from 0. `written` counts values accepted since the
 * last reset, `read` values played; the host sees `read` as
 * excitation_consumed.
 *
 * Values are kept in binary32: what the host sends as F32 is kept exactly;
 * an integer format's count x scale is rounded to binary32.
 */
#ifndef FIFO_H
#define FIFO_H

#include <stdint.h>

#include "board_config.h"

struct fifo {
	float values[BOARD_EXCITATION_CAPACITY];
	uint32_t written;
	uint32_t read;
};

static inline void fifo_reset(struct fifo *f)
{
	f->written = 0;
	f->read = 0;
}

static inline uint32_t fifo_level(const struct fifo *f)
{
	return f->written - f->read;
}

static inline void fifo_push(struct fifo *f, float value)
{
	f->values[f->written % BOARD_EXCITATION_CAPACITY] = value;
	f->written++;
}

/* The next value; only when fifo_level() > 0. */
static inline float fifo_pop(struct fifo *f)
{
	float v = f->values[f->read % BOARD_EXCITATION_CAPACITY];
	f->read++;
	return v;
}

#endif
