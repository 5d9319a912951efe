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

/* One byte of a COBS stream; at a delimiter, records
 * "event,type,seq,encoded_len,first_byte_t_us". */
void frame_byte(struct emu *e, struct frame_peek *f, uint8_t byte, const char *event)
{
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
	f->len = f->raw_len = 0;
}
