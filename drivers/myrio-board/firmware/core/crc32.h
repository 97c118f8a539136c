/*
 * CRC-32 IEEE 802.3 (zlib.crc32): polynomial 0x04C11DB7 reflected, initial
 * value and final XOR 0xFFFFFFFF (PROTOCOL.md section 2).
 */
#ifndef CRC32_H
#define CRC32_H

#include <stddef.h>
#include <stdint.h>

#define CRC32_INIT 0xFFFFFFFFu

/* Running form: start from CRC32_INIT, feed bytes, finish with crc32_final(). */
uint32_t crc32_byte(uint32_t crc, uint8_t byte);

static inline uint32_t crc32_final(uint32_t crc)
{
	return crc ^ 0xFFFFFFFFu;
}

/* CRC-32 of a whole buffer. crc32("123456789", 9) == 0xCBF43926. */
uint32_t crc32(const uint8_t *data, size_t n);

#endif
