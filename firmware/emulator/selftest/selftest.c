/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * selftest.c - a tiny AVR program that exercises every wire of the emulated-board harness,
 * so the harness is tested before (and apart from) the real firmware. Same pins as the
 * firmware (firmware/avr/pins.h), UART0 at DTHC_UART_BAUD, interrupt-driven receive.
 *
 * Commands, one per line ('\n'), each answered with one line:
 *   E<text>   -> E<text>                      echo (the pty round trip)
 *   U<n>/D<n> -> S<n>                         n STEP pulses with DIR up/down, ~20 kHz
 *   A         -> A<counts>                    one conversion of PIN_ARC_ADC (AVcc ref)
 *   I         -> I<hex>                       inputs, protocol bit order, 1 = active (LOW)
 *   T1/T0     -> T1/T0                        torch relay output
 *   O1/O0     -> O1/O0                        ohmic-sense enable output
 *   C1/C0     -> C1/C0                        copy mode: the torch output follows ESTOP
 *   R         -> R<hex>                       MCUSR as it was at boot
 *   K         -> K<n>                         Timer1 compare ticks (1 ms) counted over 20
 *                                             rounds of: tick masked 1.2 ms, unmasked 0.3 ms
 *                                             (an AVR takes a masked tick on unmask: ~30)
 *   W         -> W, then hangs: the watchdog (15 ms) resets the MCU
 *   F         -> 0x00, a COBS frame (PROTOCOL.md §9's ACK of seq 4), then F
 * A 0x00 byte (a frame delimiter) ends a line without a reply: frames sent to it are
 * swallowed, so a test can send real frames and read the host's record of them.
 * At boot it prints "BOOT <MCUSR hex>".
 */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/wdt.h>
#include <stdint.h>
#include <stdlib.h>

#include "pins.h"

#define CAT_(a, b) a##b
#define CAT(a, b) CAT_(a, b)
#define PORT_OF(p) CAT(PORT, p)
#define DDR_OF(p) CAT(DDR, p)
#define PIN_OF(p) CAT(PIN, p)

#define OUT_HIGH(n) (PORT_OF(n##_PORT) |= (uint8_t)(1u << n##_BIT))
#define OUT_LOW(n) (PORT_OF(n##_PORT) &= (uint8_t) ~(1u << n##_BIT))
#define OUT_INIT(n) (DDR_OF(n##_PORT) |= (uint8_t)(1u << n##_BIT))
#define IN_INIT(n)                                                     \
	do {                                                           \
		DDR_OF(n##_PORT) &= (uint8_t) ~(1u << n##_BIT);        \
		PORT_OF(n##_PORT) |= (uint8_t)(1u << n##_BIT);         \
	} while (0)
#define IN_ACTIVE(n) ((PIN_OF(n##_PORT) & (1u << n##_BIT)) == 0)

static volatile uint16_t ticks;

ISR(TIMER1_COMPA_vect)
{
	OCR1A += 2000; /* 1 ms at clk/8 */
	ticks++;
}

static void wait_counts(uint16_t n)
{
	uint16_t start = TCNT1;
	while ((uint16_t)(TCNT1 - start) < n)
		;
}

static uint16_t masked_ticks(void)
{
	TCCR1A = 0;
	TCCR1B = (uint8_t)(1 << CS11); /* normal mode, clk/8: 2 counts per us */
	OCR1A = (uint16_t)(TCNT1 + 2000);
	TIFR1 = (uint8_t)(1 << OCF1A);
	ticks = 0;
	TIMSK1 = (uint8_t)(1 << OCIE1A);
	for (uint8_t i = 0; i < 20; i++) {
		TIMSK1 = 0;
		wait_counts(2400);
		TIMSK1 = (uint8_t)(1 << OCIE1A);
		wait_counts(600);
	}
	TIMSK1 = 0;
	return ticks;
}

static volatile uint8_t rx_buf[128];
static volatile uint8_t rx_head, rx_tail;
static uint8_t boot_mcusr;
static uint8_t copy_mode;

#ifdef USART0_RX_vect
ISR(USART0_RX_vect)
#else
ISR(USART_RX_vect)
#endif
{
	uint8_t c = UDR0;
	uint8_t next = (uint8_t)((rx_head + 1) & 127);
	if (next != rx_tail) {
		rx_buf[rx_head] = c;
		rx_head = next;
	}
}

static void put(char c)
{
	while (!(UCSR0A & (1 << UDRE0)))
		;
	UDR0 = (uint8_t)c;
}

static void puts_(const char *s)
{
	while (*s)
		put(*s++);
}

static void put_hex(uint16_t v)
{
	char buf[6];
	utoa(v, buf, 16);
	puts_(buf);
}

static void put_dec(uint16_t v)
{
	char buf[6];
	utoa(v, buf, 10);
	puts_(buf);
}

static uint16_t inputs(void)
{
	uint16_t v = 0;
	if (IN_ACTIVE(PIN_ARC_OK))
		v |= 1u << 0;
	if (IN_ACTIVE(PIN_OHMIC))
		v |= 1u << 1;
	if (IN_ACTIVE(PIN_FLOAT))
		v |= 1u << 2;
	if (IN_ACTIVE(PIN_BREAKAWAY))
		v |= 1u << 3;
#if DTHC_HAS_THC_UPDOWN
	if (IN_ACTIVE(PIN_THC_UP))
		v |= 1u << 4;
	if (IN_ACTIVE(PIN_THC_DOWN))
		v |= 1u << 5;
#endif
	if (IN_ACTIVE(PIN_ESTOP))
		v |= 1u << 6;
#if DTHC_HAS_Z_LIMIT_INPUTS
	if (IN_ACTIVE(PIN_Z_LIMIT_MIN))
		v |= 1u << 7;
	if (IN_ACTIVE(PIN_Z_LIMIT_MAX))
		v |= 1u << 8;
#endif
	return v;
}

static void delay_cycles_25us(void)
{
	for (volatile uint8_t i = 0; i < 60; i++)
		;
}

static void steps(uint16_t n, uint8_t up)
{
	if (up)
		OUT_HIGH(PIN_DIR);
	else
		OUT_LOW(PIN_DIR);
	for (uint16_t i = 0; i < n; i++) {
		OUT_HIGH(PIN_STEP);
		delay_cycles_25us();
		OUT_LOW(PIN_STEP);
		delay_cycles_25us();
	}
}

static uint16_t adc_read(void)
{
	ADMUX = (uint8_t)((1 << REFS0) | (PIN_ARC_ADC & 7));
	ADCSRA = (uint8_t)((1 << ADEN) | (1 << ADSC) | 7);
	while (ADCSRA & (1 << ADSC))
		;
	return ADC;
}

static void command(char *line, uint8_t len)
{
	char c = line[0];
	line[len] = 0;
	switch (c) {
	case 'E':
		puts_(line);
		break;
	case 'U':
	case 'D': {
		uint16_t n = (uint16_t)atoi(line + 1);
		steps(n, c == 'U');
		put('S');
		put_dec(n);
		break;
	}
	case 'A':
		put('A');
		put_dec(adc_read());
		break;
	case 'I':
		put('I');
		put_hex(inputs());
		break;
	case 'T':
		if (line[1] == '1')
			OUT_HIGH(PIN_TORCH);
		else
			OUT_LOW(PIN_TORCH);
		puts_(line);
		break;
	case 'O':
		if (line[1] == '1')
			OUT_HIGH(PIN_OHMIC_ENABLE);
		else
			OUT_LOW(PIN_OHMIC_ENABLE);
		puts_(line);
		break;
	case 'C':
		copy_mode = line[1] == '1';
		puts_(line);
		break;
	case 'F': {
		static const uint8_t ack[] = {0x09, 0x80, 0x04, 0x34, 0x12, 0xED, 0x5E, 0x45, 0xF8, 0x00};
		put(0); /* a lone delimiter ends the text sent before */
		for (uint8_t i = 0; i < sizeof ack; i++)
			put((char)ack[i]);
		put('F');
		break;
	}
	case 'K':
		put('K');
		put_dec(masked_ticks());
		break;
	case 'W':
		puts_("W\n");
		wdt_enable(WDTO_15MS);
		for (;;)
			;
	case 'R':
		put('R');
		put_hex(boot_mcusr);
		break;
	default:
		puts_("?");
		puts_(line);
	}
	put('\n');
}

int main(void)
{
	boot_mcusr = MCUSR;
	MCUSR = 0;
	wdt_disable(); /* a watchdog reset leaves it running */
	OUT_INIT(PIN_STEP);
	OUT_INIT(PIN_DIR);
	OUT_INIT(PIN_TORCH);
	OUT_INIT(PIN_OHMIC_ENABLE);
	OUT_INIT(PIN_Z_ENABLE);
	OUT_LOW(PIN_Z_ENABLE); /* driver enabled */
	IN_INIT(PIN_ARC_OK);
	IN_INIT(PIN_OHMIC);
	IN_INIT(PIN_FLOAT);
	IN_INIT(PIN_BREAKAWAY);
	IN_INIT(PIN_ESTOP);
#if DTHC_HAS_THC_UPDOWN
	IN_INIT(PIN_THC_UP);
	IN_INIT(PIN_THC_DOWN);
#endif
#if DTHC_HAS_Z_LIMIT_INPUTS
	IN_INIT(PIN_Z_LIMIT_MIN);
	IN_INIT(PIN_Z_LIMIT_MAX);
#endif
	/* 1 Mbaud: U2X, UBRR = F_CPU / (8 * baud) - 1 */
	UCSR0A = (uint8_t)(1 << U2X0);
	uint16_t ubrr = (uint16_t)(F_CPU / (8UL * DTHC_UART_BAUD) - 1);
	UBRR0H = (uint8_t)(ubrr >> 8);
	UBRR0L = (uint8_t)ubrr;
	UCSR0C = (uint8_t)((1 << UCSZ01) | (1 << UCSZ00));
	UCSR0B = (uint8_t)((1 << RXEN0) | (1 << TXEN0) | (1 << RXCIE0));
	sei();
	puts_("BOOT ");
	put_hex(boot_mcusr);
	put('\n');

	char line[72];
	uint8_t len = 0;
	for (;;) {
		if (copy_mode) {
			if (IN_ACTIVE(PIN_ESTOP))
				OUT_HIGH(PIN_TORCH);
			else
				OUT_LOW(PIN_TORCH);
		}
		if (rx_tail == rx_head)
			continue;
		uint8_t ch = rx_buf[rx_tail];
		rx_tail = (uint8_t)((rx_tail + 1) & 127);
		if (ch == '\n') {
			if (len)
				command(line, len);
			len = 0;
		} else if (ch == 0) {
			len = 0;
		} else if (len < sizeof line - 1) {
			line[len++] = (char)ch;
		}
	}
}
