/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * record.c - the event record (--record FILE), one line per event, flushed per line:
 *
 *     t_us,mono_s,event,field...
 *
 * t_us is simulated time in microseconds since power-on (it runs on across reboots);
 * mono_s is CLOCK_MONOTONIC in seconds (Python's time.monotonic() on Linux) when the event
 * was written. Frames are peeked with a small COBS decoder: type and seq of each frame.
 */
#include <stdarg.h>
#include <string.h>
#include <time.h>

#include "host.h"

double mono_s(void)
{
	struct timespec ts;
	clock_gettime(CLOCK_MONOTONIC, &ts);
	return (double)ts.tv_sec + (double)ts.tv_nsec / 1e9;
}

int record_open(struct emu *e)
{
	if (!e->record_path)
		return 0;
	e->record = fopen(e->record_path, "w");
	if (!e->record) {
		perror(e->record_path);
		return -1;
	}
	setvbuf(e->record, NULL, _IOLBF, 0);
	fprintf(e->record, "# dthc emulated board record v1: t_us,mono_s,event,fields...\n");
	return 0;
}

void record_event(struct emu *e, const char *event, const char *fmt, ...)
{
	if (!e->record)
		return;
	va_list ap;
	fprintf(e->record, "%llu,%.6f,%s,", (unsigned long long)board_us(e), mono_s(), event);
	va_start(ap, fmt);
	vfprintf(e->record, fmt, ap);
	va_end(ap);
	fputc('\n', e->record);
}

void record_close(struct emu *e)
{
	if (e->record)
		fclose(e->record);
	e->record = NULL;
}

/* Frame loss on the board's stream (the fault matrix's flaky link, `drop RATE SECONDS` on
 * the control channel): while it lasts, each board frame is lost whole with probability
 * RATE, decided at its first byte. frame_byte runs right after the UART hook queued the
 * byte for the pty (board.c), so a lost frame's bytes are taken back off the queue's end
 * before they are ever written, its delimiter too: the host sees the frames around it
 * intact. The frame is still recorded (board_frame, what the firmware wrote), then
 * `frame_lost`. */
static struct {
	double rate;
	double until_s; /* CLOCK_MONOTONIC */
	uint64_t rng;
	int dropping; /* the frame now being written is lost */
	uint64_t lost;
} link_drop;

void record_link_drop(struct emu *e, double rate, double for_s)
{
	link_drop.rate = rate;
	link_drop.until_s = mono_s() + for_s;
	if (!link_drop.rng)
		link_drop.rng = e->seed * 0x9E3779B97F4A7C15ULL + 1;
	record_event(e, "link_drop", "%.4f,%.3f", rate, for_s);
}

uint64_t record_frames_lost(void)
{
	return link_drop.lost;
}

static double drop_uniform(void)
{
	uint64_t x = link_drop.rng; /* xorshift64 */
	x ^= x << 13;
	x ^= x >> 7;
	x ^= x << 17;
	link_drop.rng = x;
	return (double)(x >> 11) / 9007199254740992.0;
}

/* The byte the UART hook just queued is taken back (never when the queue was full: the
 * hook dropped it itself). */
static void take_back(struct emu *e, uint8_t byte)
{
	if (e->tx_len > 0 && e->tx_len < EMU_TX_BUFFER && e->tx[e->tx_len - 1] == byte)
		e->tx_len--;
}

/* One byte of a COBS stream; at a delimiter, records
 * "event,type,seq,encoded_len,first_byte_t_us". */
void frame_byte(struct emu *e, struct frame_peek *f, uint8_t byte, const char *event)
{
	if (f == &e->tx_frame) {
		if (byte != 0 && f->len == 0)
			link_drop.dropping = link_drop.rate > 0.0 && mono_s() < link_drop.until_s &&
					     drop_uniform() < link_drop.rate;
		if (link_drop.dropping)
			take_back(e, byte);
	}
	if (byte != 0) {
		if (f->len == 0)
			f->start_us = board_us(e);
		if (f->raw_len < (int)sizeof f->raw)
			f->raw[f->raw_len++] = byte;
		f->len++;
		return;
	}
	if (f->len == 0)
		return; /* a lone delimiter: an empty frame */
	uint8_t dec[EMU_FRAME_PEEK];
	int out = 0, i = 0;
	while (i < f->raw_len && out < EMU_FRAME_PEEK) {
		int code = f->raw[i++];
		int k;
		for (k = 1; k < code && i < f->raw_len && out < EMU_FRAME_PEEK; k++)
			dec[out++] = f->raw[i++];
		if (k == code && code < 0xFF && i < f->len && out < EMU_FRAME_PEEK)
			dec[out++] = 0;
	}
	if (out >= 2)
		record_event(e, event, "0x%02x,%u,%d,%llu", dec[0], dec[1], f->len,
			     (unsigned long long)f->start_us);
	else
		record_event(e, event, "?,?,%d,%llu", f->len, (unsigned long long)f->start_us);
	if (f == &e->tx_frame && link_drop.dropping) {
		link_drop.dropping = 0;
		link_drop.lost++;
		record_event(e, "frame_lost", "0x%02x,%u", out >= 1 ? dec[0] : 0,
			     out >= 2 ? dec[1] : 0);
	}
	f->len = f->raw_len = 0;
}
