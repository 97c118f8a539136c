/*
 * Short human-readable texts (NAK details, EVENT messages) without printf:
 * a small microcontroller's C library need not carry number formatting.
 */
#ifndef TEXT_H
#define TEXT_H

#include <stddef.h>
#include <stdint.h>

#define TEXT_MAX 96 /* longest detail the board sends; keeps every answer small */

struct text {
	char s[TEXT_MAX + 1];
	size_t n;
};

static inline void text_init(struct text *t)
{
	t->n = 0;
	t->s[0] = '\0';
}

static inline void text_add(struct text *t, const char *s)
{
	while (*s && t->n < TEXT_MAX)
		t->s[t->n++] = *s++;
	t->s[t->n] = '\0';
}

static inline void text_add_u32(struct text *t, uint32_t v)
{
	char digits[10];
	size_t k = 0;
	do {
		digits[k++] = (char)('0' + v % 10u);
		v /= 10u;
	} while (v);
	while (k && t->n < TEXT_MAX)
		t->s[t->n++] = digits[--k];
	t->s[t->n] = '\0';
}

#endif
