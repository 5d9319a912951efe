/*
 * hal_avr.c - firmware/hal/hal.h on the ATmega2560 (Arduino Mega) and ATmega328P (Nano).
 *
 * Timer1 (prescaler 8: 2 counts per us) runs free: its overflow extends it to the 64-bit
 * microsecond clock, and its compare A schedules the sample tick on an exact grid
 * (OCR1A += period). The tick runs board_tick with interrupts enabled (its own masked),
 * so the UART and the step generator keep their timing under a long tick.
 * Timer2 (CTC, 25 kHz) is the step generator: a 32-bit phase accumulator (DDA), one STEP
 * pulse per carry, one period long; idle (interrupt off) while Z stands still.
 * UART0 at DTHC_UART_BAUD: RX and TX ring buffers, both served by interrupts.
 * The ADC converts a burst of ADC_BURST conversions per tick; the next tick takes their
 * mean. The DTHC_ARC_VTOF build (Mega only) takes the arc voltage from a voltage-to-
 * frequency card on T5 instead (arc_vtof.c): the ADC then only feeds hal_entropy32.
 */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/wdt.h>
#include <util/atomic.h>

#include "../../firmware_protocol/c/dthc_protocol.h"
#include "../board/board.h"
#include "../hal/hal.h"
#include "hal_avr.h"
#include "pins.h"
#if DTHC_ARC_VTOF
#include "arc_vtof.h"
#endif

#define CAT_(a, b) a##b
#define CAT(a, b) CAT_(a, b)
#define PORT_OF(n) CAT(PORT, n##_PORT)
#define DDR_OF(n) CAT(DDR, n##_PORT)
#define PINR_OF(n) CAT(PIN, n##_PORT)
#define BIT_OF(n) _BV(n##_BIT)
#define OUT_INIT(n) (DDR_OF(n) |= BIT_OF(n))
#define OUT_SET(n, on) ((on) ? (PORT_OF(n) |= BIT_OF(n)) : (PORT_OF(n) &= (uint8_t)~BIT_OF(n)))
#define IN_INIT(n) (DDR_OF(n) &= (uint8_t)~BIT_OF(n), PORT_OF(n) |= BIT_OF(n)) /* pull-up */
#define IN_ACTIVE(n) ((PINR_OF(n) & BIT_OF(n)) ? 0u : 1u)                      /* active LOW */

#if defined(__AVR_ATmega328P__)
#define UART_RX_vect USART_RX_vect
#define UART_UDRE_vect USART_UDRE_vect
#else
#define UART_RX_vect USART0_RX_vect
#define UART_UDRE_vect USART0_UDRE_vect
#endif

/* --- UART rings (sizes: powers of two, set per MCU in the Makefile) ----------------------- */

#ifndef HAL_RX_RING
#define HAL_RX_RING 512 /* > a 300-byte burst at 1 Mbaud while the main loop is busy */
#endif
#ifndef HAL_TX_RING
#define HAL_TX_RING 256
#endif
typedef char hal_rx_ring_pow2[(HAL_RX_RING & (HAL_RX_RING - 1)) == 0 ? 1 : -1];
typedef char hal_tx_ring_pow2[(HAL_TX_RING & (HAL_TX_RING - 1)) == 0 ? 1 : -1];
typedef char hal_tx_ring_8bit[HAL_TX_RING <= 256 ? 1 : -1]; /* 8-bit indices */
#define TX_MASK ((uint8_t)(HAL_TX_RING - 1u))

static uint8_t rx_ring[HAL_RX_RING];
static volatile uint16_t rx_head; /* written by the RX interrupt */
static uint16_t rx_tail;          /* written by the main loop */
static uint8_t tx_ring[HAL_TX_RING];
static volatile uint8_t tx_head; /* written by the producers (tick, locked main loop) */
static volatile uint8_t tx_tail; /* written by the UDRE interrupt */

/* Arrival times of the delimiters in the receive ring, in order (the lease runs from a
 * frame's arrival), as the low 16 bits of the µs clock: the main loop takes a frame's age
 * from them, which is exact while it is less than 65 ms behind (the ring holds 5 ms of
 * line time at 1 Mbaud). More than HAL_DELIM_TIMES frames behind, the main loop takes a
 * later frame's time for an older one, so the lease runs from a little later. */
#ifndef HAL_DELIM_TIMES
#if defined(__AVR_ATmega328P__)
#define HAL_DELIM_TIMES 4 /* RAM is short on the Nano */
#else
#define HAL_DELIM_TIMES 16
#endif
#endif
static volatile uint16_t delim_us16[HAL_DELIM_TIMES];
static volatile uint8_t delim_in; /* written by the RX interrupt */
static uint8_t delim_out;         /* written by the main loop */
static uint32_t last_delim_us;

/* The receive interrupt keeps up with the line (a byte every 10 us at 1 Mbaud) while the
 * main loop decodes at about 35 us a byte: bytes no frame can use are discarded here, at
 * once, and every frame that loses a byte is still counted once (a garbage storm drops
 * nothing unseen):
 * - past the longest legal frame (DTHC_MAX_ENCODED_FRAME + 1 bytes: enough for the codec
 *   to count it TOO_LONG) the rest of the run up to its delimiter is discarded;
 * - a frame that meets a full ring loses the rest of its bytes; its start and its
 *   delimiter reach the codec, which counts the truncated frame (a CRC or framing error):
 *   data bytes take a slot only while two are free, so the delimiter of a frame begun in
 *   the ring always finds one;
 * - a frame of which no byte found room never reaches the codec: counted here
 *   (hal_uart_rx_frames_lost, added to the framing errors the board reports).
 * hal_rx_discarded counts the bytes discarded here. */
volatile uint16_t hal_rx_discarded;
static volatile uint16_t rx_frames_lost;
/* The run since the last delimiter, in one word (RAM is short on the Nano): its length in
 * non-delimiter bytes (saturating at RX_RUN_MAX) and two flags. */
static uint16_t rx_run;
#define RX_RUN_KEPT 0x8000u /* a byte of this run is in the ring */
#define RX_RUN_CUT 0x4000u  /* this run lost a byte for want of room */
#define RX_RUN_LEN 0x3FFFu
#define RX_RUN_USEFUL (DTHC_MAX_ENCODED_FRAME + 1u)
#define RX_RUN_MAX (RX_RUN_USEFUL + 1u)

static volatile uint32_t t1_overflows; /* Timer1 overflows: the clock's high part */

/* The low 16 bits of hal_time_us, interrupts off, inline: the receive interrupt stamps each
 * delimiter without a call. A call in an interrupt makes avr-gcc save every call-clobbered
 * register on entry, for every byte: at 1 Mbaud that took most of the CPU, and a burst of
 * 30 valid frames slowed the tick to 1.8 ms and latched INTERNAL (tick overrun). */
static inline uint16_t clock_us16_isr(void)
{
    uint16_t c = TCNT1;
    uint8_t o = *(volatile uint8_t *)&t1_overflows; /* its low byte (little-endian) */
    if ((TIFR1 & _BV(TOV1)) && c < 0x8000u) {
        o++;
    }
    return (uint16_t)(((uint16_t)(o & 1u) << 15) | (c >> 1));
}

ISR(UART_RX_vect)
{
    uint8_t b = UDR0;
    uint16_t head = rx_head;
    uint16_t used = (uint16_t)((head - rx_tail) & (HAL_RX_RING - 1u));
    uint16_t free_slots = (uint16_t)(HAL_RX_RING - 1u - used);
    uint16_t run = rx_run;
    if (b != 0) {
        if ((run & RX_RUN_LEN) < RX_RUN_MAX) {
            run++;
        }
        if ((run & RX_RUN_CUT) || (run & RX_RUN_LEN) > RX_RUN_USEFUL) {
            rx_run = run;
            hal_rx_discarded++;
            return;
        }
        if (free_slots < 2u) {
            rx_run = run | RX_RUN_CUT;
            hal_rx_discarded++;
            return;
        }
        rx_run = run | RX_RUN_KEPT;
    } else {
        rx_run = 0;
        if (!(run & RX_RUN_KEPT)) {
            if (run) {
                rx_frames_lost++; /* none of it reached the codec */
            }
            return; /* nothing to end: an idle delimiter the codec would ignore */
        }
        /* a run begun in the ring: its delimiter has the slot its last byte left */
    }
    rx_ring[head] = b;
    rx_head = (uint16_t)((head + 1u) & (HAL_RX_RING - 1u));
    if (b == 0) {
        delim_us16[delim_in & (HAL_DELIM_TIMES - 1u)] = clock_us16_isr();
        delim_in++;
    }
}

uint16_t hal_uart_rx_frames_lost(void)
{
    uint16_t n;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { n = rx_frames_lost; }
    return n;
}

ISR(UART_UDRE_vect)
{
    uint8_t t = tx_tail;
    if (t == tx_head) {
        UCSR0B &= (uint8_t)~_BV(UDRIE0);
        return;
    }
    UDR0 = tx_ring[t];
    tx_tail = (uint8_t)((t + 1u) & TX_MASK);
}

int16_t hal_uart_getc(void)
{
    uint16_t head;
    uint8_t b;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { head = rx_head; }
    if (head == rx_tail) {
        return -1;
    }
    b = rx_ring[rx_tail];
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        rx_tail = (uint16_t)((rx_tail + 1u) & (HAL_RX_RING - 1u));
        if (b == 0) {
            if ((uint8_t)(delim_in - delim_out) > HAL_DELIM_TIMES) {
                delim_out = (uint8_t)(delim_in - HAL_DELIM_TIMES); /* overwritten: see above */
            }
            uint32_t now = hal_time_us();
            uint16_t age = (uint16_t)((uint16_t)now - delim_us16[delim_out & (HAL_DELIM_TIMES - 1u)]);
            last_delim_us = now - age;
            delim_out++;
        }
    }
    return b;
}

uint32_t hal_uart_delimiter_us(void)
{
    return last_delim_us;
}

bool hal_uart_rx_pending(void)
{
    uint16_t head;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { head = rx_head; }
    return head != rx_tail;
}

uint16_t hal_uart_tx_free(void)
{
    return (uint8_t)((tx_tail - tx_head - 1u) & TX_MASK); /* tx_tail: one byte, atomic */
}

bool hal_uart_write(const uint8_t *data, uint16_t n)
{
    uint8_t *dst;
    uint8_t *wrap = tx_ring + HAL_TX_RING;
    uint8_t k = 0;
    if (n > hal_uart_tx_free()) {
        return false;
    }
    /* Each byte is handed to the transmit interrupt as soon as it is in the ring (tx_head:
     * one byte, atomic), so the line starts while the copy runs; the interrupt is enabled
     * once two bytes are in (the UART takes two at once: enabled after one, it would catch
     * up and stop), and again at the end. A pointer walk: half the cycles of indexing the
     * ring. The producers never run concurrently (the tick, or the main loop with the tick
     * locked): no other frame slips in between. */
    dst = tx_ring + tx_head;
    while (n--) {
        *dst++ = *data++;
        if (dst == wrap) {
            dst = tx_ring;
        }
        tx_head = (uint8_t)(dst - tx_ring);
        if (++k == 2) {
            ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { UCSR0B |= _BV(UDRIE0); }
        }
    }
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { UCSR0B |= _BV(UDRIE0); }
    return true;
}

static void uart_init(void)
{
    /* Double speed: 16 MHz / (8 * 1 Mbaud) - 1 = 1, exact. */
    uint16_t ubrr = (uint16_t)((F_CPU + 4UL * DTHC_UART_BAUD) / (8UL * DTHC_UART_BAUD) - 1UL);
    UBRR0H = (uint8_t)(ubrr >> 8);
    UBRR0L = (uint8_t)ubrr;
    UCSR0A = _BV(U2X0);
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00); /* 8N1 */
    UCSR0B = _BV(RXEN0) | _BV(TXEN0) | _BV(RXCIE0);
}

/* --- time and the sample tick --------------------------------------------------------------- */

/* t1_overflows is declared before the receive interrupt, which reads it. */
static uint32_t tick_t_us;
static uint16_t tick_period_us = 1000; /* Timer1 counts twice per us */

ISR(TIMER1_OVF_vect)
{
    t1_overflows++;
}

/* Overflows and count read together; an overflow pending but not yet served counts. */
static void clock_read(uint32_t *ovf, uint16_t *count)
{
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        uint16_t c = TCNT1;
        uint32_t o = t1_overflows;
        if ((TIFR1 & _BV(TOV1)) && c < 0x8000u) {
            o++;
        }
        *ovf = o;
        *count = c;
    }
}

uint32_t hal_time_us(void)
{
    uint32_t o;
    uint16_t c;
    clock_read(&o, &c);
    /* (o << 15) + (c >> 1) without a 15-step shift loop: byte moves and one shift. */
    return (uint32_t)((((uint32_t)(uint16_t)o << 16) | c) >> 1)
           | ((uint32_t)((uint16_t)(o >> 16) & 1u) << 31);
}

uint64_t hal_time_us64(void)
{
    uint32_t o;
    uint16_t c;
    clock_read(&o, &c);
    return ((uint64_t)o << 15) + (c >> 1);
}

void hal_tick_set_period_us(uint16_t period_us)
{
    tick_period_us = period_us;
#if DTHC_ARC_VTOF
    arc_vtof_set_period_us(period_us);
#endif
}

void hal_tick_lock(void)
{
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { TIMSK1 &= (uint8_t)~_BV(OCIE1A); }
}

void hal_tick_unlock(void)
{
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { TIMSK1 |= _BV(OCIE1A); }
}

/* Self-check state in the general purpose I/O registers, not RAM (the Nano's is spent):
 * GPIOR0 the HAL_HEALTH_* bits not yet read (bit 7: an ADC burst is under way), GPIOR1 the
 * ticks since the main loop last kicked the watchdog. */
#define HEALTH GPIOR0
#define HEALTH_ADC_ARMED 0x80u
/* The tick running now is a late one, run at once after the previous (catching up): the
 * ADC burst that tick started has had no time to convert, which is no failure. */
#define HEALTH_CATCHING_UP 0x40u
#define HAL_HEALTH_ALL (HAL_HEALTH_TICK_OVERRUN | HAL_HEALTH_ADC_INCOMPLETE | HAL_HEALTH_LOOP_STALL)
#define LOOP_SILENT_TICKS GPIOR1
/* Three periods behind is an overrun, not jitter (a long interrupt burst delays one tick). */
#define HAL_TICK_OVERRUN_PERIODS 3u
/* Half the watchdog's 120 ms: the main loop came that close to a reset. */
#define HAL_LOOP_STALL_US 60000UL

ISR(TIMER1_COMPA_vect)
{
    uint8_t behind = 0;
    TIMSK1 &= (uint8_t)~_BV(OCIE1A); /* never re-entered */
    for (;;) {
        uint32_t t = tick_t_us;
        tick_t_us += tick_period_us;
        OCR1A += (uint16_t)(tick_period_us << 1);
        sei();
        board_tick(t);
        cli();
        TIFR1 = _BV(OCF1A); /* a match during the tick is the one just run, or the next: */
        if ((int16_t)(TCNT1 - OCR1A) < 0) {
            break; /* the next tick is still ahead: its match will fire */
        }
        /* behind by a period: run it now, with its scheduled time */
        if (++behind >= HAL_TICK_OVERRUN_PERIODS) {
            HEALTH |= HAL_HEALTH_TICK_OVERRUN;
        }
        HEALTH |= HEALTH_CATCHING_UP;
    }
    HEALTH &= (uint8_t)~HEALTH_CATCHING_UP;
    TIMSK1 |= _BV(OCIE1A);
    if (++LOOP_SILENT_TICKS == 0) {
        LOOP_SILENT_TICKS = 0xFFu; /* saturates */
    }
    if ((uint32_t)LOOP_SILENT_TICKS * tick_period_us >= HAL_LOOP_STALL_US) {
        HEALTH |= HAL_HEALTH_LOOP_STALL;
    }
}

uint8_t hal_health(void)
{
    uint8_t health;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        health = HEALTH & HAL_HEALTH_ALL;
        HEALTH = (uint8_t)(HEALTH & (uint8_t)~HAL_HEALTH_ALL);
    }
    return health;
}

void hal_watchdog_kick(void)
{
    wdt_reset();
    LOOP_SILENT_TICKS = 0;
}

static void timer1_init(void)
{
    TCCR1A = 0;
    TCCR1B = _BV(CS11); /* normal mode, clk/8 */
    TCNT1 = 0;
    tick_t_us = (uint32_t)tick_period_us;
    OCR1A = (uint16_t)(tick_period_us << 1);
    TIFR1 = _BV(OCF1A) | _BV(TOV1);
    TIMSK1 = _BV(TOIE1) | _BV(OCIE1A);
}

/* --- step generator ------------------------------------------------------------------------- */

#define DDA_HZ 25000UL
#define DDA_OCR (F_CPU / 8UL / DDA_HZ - 1UL)
#define DDA_MAX_RATE ((int32_t)(DDA_HZ / 2UL - 1UL)) /* one pulse spans a DDA period */
#define DDA_INC_PER_STEP_S 171799UL                  /* 2^32 / 25000, rounded */

static volatile int32_t z_steps;
static uint32_t dda_phase;
static uint32_t dda_inc;
static int32_t dda_lo;
static int32_t dda_hi;
static uint8_t dda_up;   /* wanted direction */
static uint8_t dir_up;   /* the DIR pin now */

ISR(TIMER2_COMPA_vect)
{
    uint32_t p;
    OUT_SET(PIN_STEP, 0); /* ends the pulse of the previous period */
    if (dda_up != dir_up) {
        dir_up = dda_up;
        OUT_SET(PIN_DIR, dir_up); /* DIR set a whole period before the next STEP edge */
        return;
    }
    p = dda_phase + dda_inc;
    if (p < dda_phase) {
        if (dir_up) {
            if (z_steps < dda_hi) {
                z_steps++;
                OUT_SET(PIN_STEP, 1);
            }
        } else if (z_steps > dda_lo) {
            z_steps--;
            OUT_SET(PIN_STEP, 1);
        }
    }
    dda_phase = p;
}

void hal_z_drive(int32_t rate_steps_s, int32_t lo_steps, int32_t hi_steps)
{
    uint8_t up = rate_steps_s > 0;
    uint32_t rate = (uint32_t)(up ? rate_steps_s : -rate_steps_s);
    if (rate > (uint32_t)DDA_MAX_RATE) {
        rate = (uint32_t)DDA_MAX_RATE;
    }
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        dda_inc = rate * DDA_INC_PER_STEP_S;
        dda_lo = lo_steps;
        dda_hi = hi_steps;
        if (rate) {
            dda_up = up;
            TIMSK2 |= _BV(OCIE2A);
        } else {
            TIMSK2 &= (uint8_t)~_BV(OCIE2A); /* standing still: no 25 kHz interrupt */
            OUT_SET(PIN_STEP, 0);
        }
    }
}

int32_t hal_z_steps(void)
{
    int32_t s;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { s = z_steps; }
    return s;
}

static void timer2_init(void)
{
    TCCR2A = _BV(WGM21); /* CTC */
    TCCR2B = _BV(CS21);  /* clk/8 */
    OCR2A = (uint8_t)DDA_OCR;
    TIMSK2 = 0;
}

/* --- ADC ------------------------------------------------------------------------------------ */

#if !DTHC_ARC_VTOF /* the ADC front end; the V-to-F one is arc_vtof.c */

#define ADC_BURST 4 /* conversions per sample, averaged (about 420 us at 125 kHz) */
#define ADC_BURST_LOG2 2
#define ARC_CV_PER_COUNT_X1024 ((uint32_t)DTHC_ADC_REF_MV * DTHC_ARC_DIVIDER / 10u)
/* 4 x 1023 counts times the factor must fit 32 bits. */
typedef char hal_arc_scale_fits[(ARC_CV_PER_COUNT_X1024 <= 1000000UL) ? 1 : -1];
static volatile uint16_t adc_sum;
static volatile uint8_t adc_n;
static volatile uint8_t adc_left;
static uint16_t arc_last_cv;

ISR(ADC_vect)
{
    adc_sum += ADC;
    adc_n++;
    if (--adc_left) {
        ADCSRA |= _BV(ADSC);
    }
}

/* The mean of the burst started at the previous tick, then the next burst. Bursts, not a
 * free-running ADC: a few interrupts per sample instead of ten (cheaper on simavr too). */
uint16_t hal_arc_raw(void)
{
    uint16_t sum;
    uint8_t n;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        sum = adc_sum;
        n = adc_n;
        if ((HEALTH & (HEALTH_ADC_ARMED | HEALTH_CATCHING_UP)) == HEALTH_ADC_ARMED && n == 0) {
            /* Not one conversion of the burst started a period ago completed: the ADC has
             * stopped. (A burst cut short, at 2 kHz with a late tick, is averaged below.) */
            HEALTH |= HAL_HEALTH_ADC_INCOMPLETE;
        }
        adc_sum = 0;
        adc_n = 0;
        adc_left = ADC_BURST;
        if (!(ADCSRA & _BV(ADSC))) {
            ADCSRA |= _BV(ADSC);
        }
        HEALTH |= HEALTH_ADC_ARMED;
    }
    /* Arc centivolts = counts * Vref_mV * divider / 1024 / 10, from the mean; a whole
     * burst divides by a shift (the usual case: no 40 us division in the tick). */
    if (n == ADC_BURST) {
        arc_last_cv = (uint16_t)(((uint32_t)sum * ARC_CV_PER_COUNT_X1024) >> (10 + ADC_BURST_LOG2));
    } else if (n) {
        arc_last_cv = (uint16_t)(((uint32_t)sum * ARC_CV_PER_COUNT_X1024 / n) >> 10);
    }
    return arc_last_cv;
}
#endif /* !DTHC_ARC_VTOF */

static uint16_t adc_read_blocking(void)
{
    ADCSRA |= _BV(ADSC);
    while (ADCSRA & _BV(ADSC)) {
    }
    return ADC;
}

static void adc_init(void)
{
    ADMUX = _BV(REFS0) | (PIN_ARC_ADC & 0x07); /* AVcc reference */
#if defined(MUX5)
    ADCSRB = (PIN_ARC_ADC & 0x08) ? _BV(MUX5) : 0;
#endif
    ADCSRA = _BV(ADEN) | _BV(ADPS2) | _BV(ADPS1) | _BV(ADPS0); /* 125 kHz: 104 us/conv */
}

static void adc_start(void)
{
#if DTHC_ARC_VTOF
    arc_vtof_start(); /* the clock runs: the first sample's counts start here */
#else
    ADCSRA |= _BV(ADIE);
#endif
}

/* --- outputs and inputs ---------------------------------------------------------------------- */

void hal_set_torch(bool on)
{
    OUT_SET(PIN_TORCH, on);
}

void hal_set_ohmic_enable(bool on)
{
    OUT_SET(PIN_OHMIC_ENABLE, on);
}

uint16_t hal_inputs(void)
{
    uint16_t in = (uint16_t)(IN_ACTIVE(PIN_ARC_OK) << DTHC_INPUT_ARC_OK);
    in |= (uint16_t)(IN_ACTIVE(PIN_OHMIC) << DTHC_INPUT_OHMIC);
    in |= (uint16_t)(IN_ACTIVE(PIN_FLOAT) << DTHC_INPUT_FLOAT);
    in |= (uint16_t)(IN_ACTIVE(PIN_BREAKAWAY) << DTHC_INPUT_BREAKAWAY);
    in |= (uint16_t)(IN_ACTIVE(PIN_ESTOP) << DTHC_INPUT_ESTOP);
#if DTHC_HAS_THC_UPDOWN
    in |= (uint16_t)(IN_ACTIVE(PIN_THC_UP) << DTHC_INPUT_THC_UP);
    in |= (uint16_t)(IN_ACTIVE(PIN_THC_DOWN) << DTHC_INPUT_THC_DOWN);
#endif
#if DTHC_HAS_Z_LIMIT_INPUTS
    in |= (uint16_t)(IN_ACTIVE(PIN_Z_LIMIT_MIN) << DTHC_INPUT_Z_LIMIT_MIN);
    in |= (uint16_t)(IN_ACTIVE(PIN_Z_LIMIT_MAX) << DTHC_INPUT_Z_LIMIT_MAX);
#endif
    return in;
}

static void pins_init(void)
{
    /* Outputs first, all inactive: torch off, ohmic sensing off, Z driver enabled (LOW). */
    OUT_SET(PIN_TORCH, 0);
    OUT_SET(PIN_OHMIC_ENABLE, 0);
    OUT_SET(PIN_STEP, 0);
    OUT_SET(PIN_DIR, 0);
    OUT_SET(PIN_Z_ENABLE, 0);
    OUT_INIT(PIN_TORCH);
    OUT_INIT(PIN_OHMIC_ENABLE);
    OUT_INIT(PIN_STEP);
    OUT_INIT(PIN_DIR);
    OUT_INIT(PIN_Z_ENABLE);
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
}

/* --- entropy --------------------------------------------------------------------------------- */

/* Survive a reset (not a power cycle): a start counter and whatever RAM held at power-on. */
static uint32_t noinit_pool[4] __attribute__((section(".noinit")));

static uint32_t mix32(uint32_t h, uint32_t v)
{
    h ^= v;
    h *= 0x01000193UL; /* FNV-style step, then a murmur finaliser at the end */
    h ^= h >> 15;
    return h;
}

/* No XY speed input on these boards (capability XY_SPEED not advertised): never called. */
uint16_t hal_xy_speed_dmm_s(void)
{
    return DTHC_XY_SPEED_UNKNOWN;
}

uint32_t hal_entropy32(void)
{
    uint32_t h = 0x811C9DC5UL;
    uint8_t i;
    noinit_pool[0]++;
    for (i = 0; i < 4; i++) {
        h = mix32(h, noinit_pool[i]);
    }
    for (i = 0; i < 32; i++) {
        h = mix32(h, (uint32_t)adc_read_blocking() ^ ((uint32_t)TCNT1 << 16) ^ TCNT2);
    }
    h ^= h >> 16;
    h *= 0x85EBCA6BUL;
    h ^= h >> 13;
    noinit_pool[1] ^= h; /* the next start sees this one's result too */
    return h;
}

/* --- stack watermark (the measuring build) ------------------------------------------------------ */

#ifdef BOARD_TIMING
extern uint8_t __heap_start; /* the end of .bss/.noinit: the stack may grow down to here */
#define STACK_PAINT 0xA5

/* Painted before main() runs, so every byte the stack ever touches is overwritten. */
void stack_paint(void) __attribute__((naked, used, section(".init1")));
void stack_paint(void)
{
    uint8_t *p = &__heap_start;
    while (p < (uint8_t *)SP - 2) {
        *p++ = STACK_PAINT;
    }
}

/* Bytes between the static data and the deepest the stack has reached. */
uint16_t hal_stack_unused(void)
{
    const uint8_t *p = &__heap_start;
    while (*p == STACK_PAINT) {
        p++;
    }
    return (uint16_t)(p - &__heap_start);
}
#endif

/* --- start ------------------------------------------------------------------------------------ */

void hal_init(void)
{
    pins_init();
    uart_init();
    adc_init();
#if DTHC_ARC_VTOF
    arc_vtof_init();
#endif
    timer2_init();
}

void hal_start(void)
{
    timer1_init();
    adc_start();
}
