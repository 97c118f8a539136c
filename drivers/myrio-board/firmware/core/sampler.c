#include "sampler.h"

#include <float.h>
#include <math.h>

#include "wire.h"

void sampler_init(struct sampler *s)
{
	s->n_channels = 0;
	s->row_bytes = 0;
	s->block_samples = 1;
	s->block_index = 0;
	sampler_start_run(s);
}

void sampler_configure(struct sampler *s, uint8_t n_channels, const struct channel_select *ch,
		       uint16_t block_samples)
{
	s->n_channels = n_channels;
	s->row_bytes = 0;
	for (unsigned i = 0; i < n_channels; i++) {
		s->ch[i] = ch[i];
		s->row_bytes += format_bytes(ch[i].format);
	}
	s->block_samples = block_samples;
}

void sampler_start_run(struct sampler *s)
{
	s->rows = 0;
	s->overflowed = false;
	s->clipped = false;
	s->pending_flags = 0;
	s->first_sample = 0;
}

/* binary32; values beyond its range become +-infinity, not flagged (section 7) */
static float to_f32(double v)
{
	if (v > FLT_MAX)
		return INFINITY;
	if (v < -FLT_MAX)
		return -INFINITY;
	return (float)v;
}

/* count = round(value / scale), half to even, saturated to [lo, hi] (which
 * sets `clipped`); NaN is sent as 0 and not flagged (section 7). */
static int32_t to_count(double v, float scale, int32_t lo, int32_t hi, bool *clipped)
{
	double q = v / (double)scale;
	if (isnan(q))
		return 0;
	double r = nearbyint(q); /* the default rounding mode: to nearest, ties to even */
	if (r > (double)hi) {
		*clipped = true;
		return hi;
	}
	if (r < (double)lo) {
		*clipped = true;
		return lo;
	}
	return (int32_t)r;
}

bool sampler_add_row(struct sampler *s, const double row[BOARD_N_CHANNELS])
{
	size_t at = SAMPLES_PAYLOAD_HEAD + (size_t)s->rows * s->row_bytes;
	if (s->overflowed || at + s->row_bytes > sizeof s->block) {
		s->overflowed = true;
	} else {
		uint8_t *p = s->block + at;
		for (unsigned i = 0; i < s->n_channels; i++) {
			const struct channel_select *c = &s->ch[i];
			double v = row[c->channel];
			if (c->format == FMT_F32) {
				put_f32(p, to_f32(v));
				p += 4;
			} else if (c->format == FMT_I16) {
				int32_t n = to_count(v, c->scale, INT16_MIN, INT16_MAX, &s->clipped);
				put_u16(p, (uint16_t)(int16_t)n);
				p += 2;
			} else {
				int32_t n = to_count(v, c->scale, INT32_MIN, INT32_MAX, &s->clipped);
				put_u32(p, (uint32_t)n);
				p += 4;
			}
		}
	}
	s->rows++;
	return s->rows >= s->block_samples;
}

size_t sampler_seal(struct sampler *s, uint16_t seq, uint16_t flags, uint32_t consumed, uint32_t level,
		    uint32_t underruns)
{
	if (s->overflowed)
		return 0;
	uint8_t *p = s->block;
	p[0] = PROTOCOL_VERSION;
	p[1] = MSG_SAMPLES;
	put_u16(p + 2, seq);
	put_u32(p + 4, s->block_index);
	put_u32(p + 8, s->first_sample);
	put_u16(p + 12, s->rows);
	put_u16(p + 14, flags);
	put_u32(p + 16, consumed);
	put_u32(p + 20, level);
	put_u32(p + 24, underruns);
	return SAMPLES_PAYLOAD_HEAD + (size_t)s->rows * s->row_bytes;
}

void sampler_next_block(struct sampler *s)
{
	s->block_index++;
	s->first_sample += s->rows;
	s->rows = 0;
	s->overflowed = false;
	s->clipped = false;
	s->pending_flags = 0;
}
