#include "uart.h"

#include "stm32f4.h"

struct ring {
	volatile uint8_t bytes[UART_RING];
	volatile uint32_t head; /* written by the producer only */
	volatile uint32_t tail; /* written by the consumer only */
};

static struct ring rx; /* producer: the interrupt; consumer: the loop */
static struct ring tx; /* producer: the loop; consumer: the interrupt */
static volatile uint32_t overruns;

void uart_init(uint32_t baud)
{
	RCC_AHB1ENR |= RCC_AHB1ENR_GPIOAEN;
	RCC_APB1ENR |= RCC_APB1ENR_USART2EN;
	/* PA2, PA3: alternate function 7 */
	GPIOA_MODER = (GPIOA_MODER & ~(0xFu << 4)) | (0xAu << 4);
	GPIOA_AFRL = (GPIOA_AFRL & ~(0xFFu << 8)) | (0x77u << 8);
	USART2_BRR = (APB1_CLOCK_HZ + baud / 2u) / baud; /* oversampling by 16 */
	USART2_CR1 = USART_CR1_UE | USART_CR1_TE | USART_CR1_RE | USART_CR1_RXNEIE; /* 8N1 */
	NVIC_ISER(USART2_IRQ / 32u) = 1u << (USART2_IRQ % 32u);
}

void USART2_IRQHandler(void)
{
	uint32_t sr = USART2_SR;
	if (sr & (USART_SR_RXNE | USART_SR_ORE)) {
		uint8_t byte = (uint8_t)USART2_DR; /* reading DR also clears an overrun */
		if (rx.head - rx.tail < UART_RING) {
			rx.bytes[rx.head % UART_RING] = byte;
			rx.head++;
		} else {
			overruns++;
		}
	}
	if ((sr & USART_SR_TXE) && (USART2_CR1 & USART_CR1_TXEIE)) {
		if (tx.tail != tx.head) {
			USART2_DR = tx.bytes[tx.tail % UART_RING];
			tx.tail++;
		} else {
			USART2_CR1 &= ~USART_CR1_TXEIE; /* nothing left: stop asking */
		}
	}
}

size_t uart_read(uint8_t *buf, size_t max)
{
	size_t n = 0;
	while (n < max && rx.tail != rx.head) {
		buf[n++] = rx.bytes[rx.tail % UART_RING];
		rx.tail++;
	}
	return n;
}

size_t uart_write(const uint8_t *buf, size_t n)
{
	size_t taken = 0;
	while (taken < n && tx.head - tx.tail < UART_RING) {
		tx.bytes[tx.head % UART_RING] = buf[taken++];
		tx.head++;
	}
	if (taken)
		USART2_CR1 |= USART_CR1_TXEIE; /* the interrupt drains the ring */
	return taken;
}

uint32_t uart_rx_overruns(void)
{
	return overruns;
}
