/*
 * The host's serial line on a Cortex-M: USART2 driven by its interrupt, with
 * a receive and a transmit ring buffer between the interrupt and the loop.
 *
 * Each ring has one writer and one reader (the interrupt or the loop), so
 * head and tail need no lock: each side writes only its own index.
 */
#ifndef UART_H
#define UART_H

#include <stddef.h>
#include <stdint.h>

/* Bytes per ring, a power of two: 3.4 ms of line at 3 Mbaud, far more than
 * arrives between two loop ticks (250 us). */
#define UART_RING 1024u

void uart_init(uint32_t baud);
size_t uart_read(uint8_t *buf, size_t max);
size_t uart_write(const uint8_t *buf, size_t n);

/* Bytes the receive ring had no room for (the loop fell behind). */
uint32_t uart_rx_overruns(void);

#endif
