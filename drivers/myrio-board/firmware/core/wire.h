/*
 * Little-endian fields (PROTOCOL.md section 3), byte by byte so the code
 * does not depend on the processor's byte order or alignment.
 */
#ifndef WIRE_H
#define WIRE_H

#include <stddef.h>
#include <stdint.h>
#include <string.h>

static inline uint16_t get_u16(const uint8_t *p)
{
	return (uint16_t)(p[0] | (p[1] << 8));
}

static inline uint32_t get_u32(const uint8_t *p)
{
	return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}

static inline float get_f32(const uint8_t *p)
{
	uint32_t bits = get_u32(p);
	float f;
	memcpy(&f, &bits, sizeof f);
	return f;
}

static inline void put_u16(uint8_t *p, uint16_t v)
{
	p[0] = (uint8_t)v;
	p[1] = (uint8_t)(v >> 8);
}

static inline void put_u32(uint8_t *p, uint32_t v)
{
	p[0] = (uint8_t)v;
	p[1] = (uint8_t)(v >> 8);
	p[2] = (uint8_t)(v >> 16);
	p[3] = (uint8_t)(v >> 24);
}

static inline void put_f32(uint8_t *p, float f)
{
	uint32_t bits;
	memcpy(&bits, &f, sizeof bits);
	put_u32(p, bits);
}

/* Appends fields to a fixed buffer; writes past its end are dropped and
 * remembered in `overflow` (the caller's buffers are sized so it never is). */
struct writer {
	uint8_t *buf;
	size_t cap;
	size_t len;
	int overflow;
};

static inline uint8_t *writer_room(struct writer *w, size_t n)
{
	if (w->cap - w->len < n) {
		w->overflow = 1;
		return NULL;
	}
	uint8_t *p = w->buf + w->len;
	w->len += n;
	return p;
}

static inline void w_u8(struct writer *w, uint8_t v)
{
	uint8_t *p = writer_room(w, 1);
	if (p)
		p[0] = v;
}

static inline void w_u16(struct writer *w, uint16_t v)
{
	uint8_t *p = writer_room(w, 2);
	if (p)
		put_u16(p, v);
}

static inline void w_u32(struct writer *w, uint32_t v)
{
	uint8_t *p = writer_room(w, 4);
	if (p)
		put_u32(p, v);
}

static inline void w_f32(struct writer *w, float v)
{
	uint8_t *p = writer_room(w, 4);
	if (p)
		put_f32(p, v);
}

/* A protocol string: length byte, then at most 255 bytes of text. */
static inline void w_str(struct writer *w, const char *text)
{
	size_t n = strlen(text);
	if (n > 255)
		n = 255;
	uint8_t *p = writer_room(w, 1 + n);
	if (p) {
		p[0] = (uint8_t)n;
		memcpy(p + 1, text, n);
	}
}

#endif
