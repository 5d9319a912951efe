/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * board.c - the MCU on simavr and its wiring: UART0 (host bytes in at line rate, board
 * bytes out), STEP/DIR counted into a physical Z, the torch relay and ohmic-enable outputs,
 * the inputs (active LOW) and the arc ADC channel, set at each conversion.
 */
#include <errno.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include "avr_adc.h"
#include "avr_extint.h"
#include "avr_ioport.h"
#include "avr_uart.h"
#include "sim_cycle_timers.h"
#include "sim_elf.h"
#include "sim_interrupts.h"
#include "sim_io.h"

#include "host.h"

#define MCUSR_ADDR 0x54 /* MCUSR, I/O 0x34, on both the 328P and the 2560 */
#define MCUSR_PORF 0x01
#define MCUSR_EXTRF 0x02

static avr_uart_t *uart_of(struct emu *e) { return (avr_uart_t *)e->uart; }

uint64_t board_cycles(struct emu *e) { return e->cycle_base + e->avr->cycle; }

uint64_t board_us(struct emu *e) { return board_cycles(e) / EMU_CYCLES_PER_US; }

double board_z_mm(const struct emu *e)
{
	return (double)e->z_steps / (double)e->pins->steps_per_mm;
}

int board_rx_enabled(struct emu *e)
{
	avr_uart_t *u = uart_of(e);
	return avr_regbit_get(e->avr, u->rxen) != 0;
}

static int rx_fifo_full(struct emu *e)
{
	avr_uart_t *u = uart_of(e);
	unsigned next = ((unsigned)u->input.write + 1u) & (uart_fifo_fifo_size - 1u);
	return next == (unsigned)u->input.read;
}

static unsigned rx_fifo_used(struct emu *e)
{
	avr_uart_t *u = uart_of(e);
	return ((unsigned)u->input.write - (unsigned)u->input.read) & (uart_fifo_fifo_size - 1u);
}

/* Cycles one character takes at the baud rate and frame format the firmware set now
 * (UBRR0, U2X0, UCSZ0, USBS0; no parity: the UART module keeps no parity setting). */
static uint64_t byte_cycles(struct emu *e)
{
	avr_uart_t *u = uart_of(e);
	avr_t *avr = e->avr;
	unsigned ubrr = avr->data[u->ubrrl.reg];
	if (u->ubrrh.reg)
		ubrr |= (unsigned)(avr->data[u->ubrrh.reg] & 0x0f) << 8;
	unsigned div = avr_regbit_get(avr, u->u2x) ? 8u : 16u;
	static const unsigned data_bits[8] = {5, 6, 7, 8, 8, 8, 8, 9};
	unsigned size = avr_regbit_get(avr, u->ucsz) | (avr_regbit_get(avr, u->ucsz2) << 2);
	unsigned bits = 1u + data_bits[size & 7u] + 1u + (avr_regbit_get(avr, u->usbs) ? 1u : 0u);
	return (uint64_t)(ubrr + 1u) * div * bits;
}

/*
 * simavr computes the UART's character time only when UBRRnL is written, from the U2X bit
 * of that moment, and counts a parity bit that 8N1 does not have: a firmware that sets
 * UBRR before U2X (as the datasheet's examples allow) transmitted at half its baud rate
 * (22 us per byte at 1 Mbaud). The host keeps it at what the registers say now.
 */
static void sync_uart_timing(struct emu *e)
{
	avr_uart_t *u = uart_of(e);
	avr_cycle_count_t c = (avr_cycle_count_t)byte_cycles(e);
	if (u->cycles_per_byte != c)
		u->cycles_per_byte = c;
}

static avr_cycle_count_t wake_timer(struct avr_t *avr, avr_cycle_count_t when, void *param)
{
	(void)avr;
	(void)when;
	(void)param;
	return 0; /* only bounds a sleeping core's jump, so the next event is on time */
}

static int wake_rx_tag, wake_slice_tag;

static void wake_at(struct emu *e, uint64_t at_cycles, int *tag)
{
	uint64_t now = board_cycles(e);
	avr_cycle_count_t in = at_cycles > now ? at_cycles - now : 1;
	avr_cycle_timer_register(e->avr, in, wake_timer, tag);
}

/* Hand the next host byte to the receiver, at line rate, never into a full FIFO. */
static void deliver_rx(struct emu *e)
{
	uint64_t now = board_cycles(e);
	if (!board_rx_enabled(e)) {
		/* A UART that is off (reset, boot) loses what arrives, as a real one does. */
		record_event(e, "rx_dropped", "%zu,receiver_off", e->rx_len);
		e->rx_dropped += e->rx_len;
		e->rx_len = 0;
		e->rx_head = 0;
		e->rx_frame.len = e->rx_frame.raw_len = 0;
		return;
	}
	if (e->xoff && rx_fifo_used(e) > 0)
		return;
	e->xoff = 0;
	if (rx_fifo_full(e))
		return;
	uint8_t byte = e->rx[e->rx_head];
	e->rx_head = (e->rx_head + 1) % EMU_RX_BUFFER;
	e->rx_len--;
	e->rx_bytes++;
	avr_raise_irq(e->uart_in, byte);
	frame_byte(e, &e->rx_frame, byte, "host_frame");
	e->rx_next_cycle = now + byte_cycles(e);
	if (e->rx_len)
		wake_at(e, e->rx_next_cycle, &wake_rx_tag);
}

void board_queue_rx(struct emu *e, const uint8_t *data, size_t n)
{
	for (size_t i = 0; i < n; i++) {
		if (e->rx_len == EMU_RX_BUFFER) {
			e->rx_dropped++;
			continue;
		}
		e->rx[(e->rx_head + e->rx_len) % EMU_RX_BUFFER] = data[i];
		e->rx_len++;
	}
	if (e->rx_len)
		wake_at(e, e->rx_next_cycle, &wake_rx_tag);
}

static void uart_out_hook(struct avr_irq_t *irq, uint32_t value, void *param)
{
	(void)irq;
	struct emu *e = param;
	uint8_t byte = (uint8_t)value;
	e->tx_bytes++;
	if (e->tx_len < EMU_TX_BUFFER)
		e->tx[e->tx_len++] = byte;
	else
		e->tx_dropped++;
	frame_byte(e, &e->tx_frame, byte, "board_frame");
}

static void uart_xoff_hook(struct avr_irq_t *irq, uint32_t value, void *param)
{
	(void)irq;
	struct emu *e = param;
	if (value)
		e->xoff = 1;
}

static void uart_xon_hook(struct avr_irq_t *irq, uint32_t value, void *param)
{
	(void)irq;
	(void)value;
	struct emu *e = param;
	e->xoff = 0;
}

static void adc_trigger_hook(struct avr_irq_t *irq, uint32_t value, void *param)
{
	(void)irq;
	struct emu *e = param;
	union {
		avr_adc_mux_t mux;
		uint32_t v;
	} m = {.v = value};
	if (m.mux.kind != ADC_MUX_SINGLE || (int)m.mux.src != e->pins->arc_adc)
		return;
	uint64_t t = board_us(e);
	board_apply_inputs(e, 0);
	double volts = plant_arc_voltage(e, t);
	double mv = volts / (double)e->pins->arc_divider * 1000.0;
	if (mv < 0.0)
		mv = 0.0;
	if (mv > (double)e->pins->adc_ref_mv)
		mv = (double)e->pins->adc_ref_mv;
	avr_raise_irq(e->adc_irq + ADC_IRQ_ADC0 + e->pins->arc_adc, (uint32_t)(mv + 0.5));
}

/*
 * The voltage-to-frequency card (--arc-input vtof): the T5 pin toggles at twice the card's
 * frequency, each edge a simavr cycle timer. At every edge the arc voltage (the model now,
 * plus noise held for VTOF_NOISE_HOLD_US, as often as the ADC draws it) sets the frequency
 * until the next one; the edge times keep their fractions, so the mean rate is exact.
 */
double board_vtof_hz(struct emu *e, double arc_v)
{
	const struct vtof_card *c = &e->vtof;
	double in_v = arc_v / (double)e->pins->arc_divider;
	double x = c->full_v > 0.0 ? in_v / c->full_v : 0.0;
	if (x < 0.0)
		x = 0.0;
	if (x > 1.0)
		x = 1.0; /* the card saturates at its full scale */
	return c->zero_hz + (c->full_hz - c->zero_hz) * x;
}

static avr_cycle_count_t vtof_edge(struct avr_t *avr, avr_cycle_count_t when, void *param)
{
	struct emu *e = param;
	struct vtof_card *c = &e->vtof;
	(void)avr;
	c->level ^= 1;
	if (c->level)
		c->edges++;
	avr_raise_irq(e->arc_vtof.irq, (uint32_t)c->level);
	uint64_t t = board_us(e);
	double v = plant_arc_model_v(e, t);
	if (v > 0.0) {
		if (t >= c->noise_until_us) {
			c->noise_v = plant_noise(e);
			c->noise_until_us = t + VTOF_NOISE_HOLD_US;
		}
		v += c->noise_v;
		if (v < 0.0)
			v = 0.0;
	}
	e->arc.last_v = v;
	c->hz = board_vtof_hz(e, v);
	c->next_edge += (double)EMU_FREQUENCY_HZ / (2.0 * c->hz);
	avr_cycle_count_t next = (avr_cycle_count_t)(c->next_edge + 0.5);
	return next > when ? next : when + 1;
}

static void vtof_arm(struct emu *e)
{
	if (e->arc_input != ARC_INPUT_VTOF)
		return;
	struct vtof_card *c = &e->vtof;
	c->hz = board_vtof_hz(e, 0.0);
	c->next_edge = (double)e->avr->cycle + (double)EMU_FREQUENCY_HZ / (2.0 * c->hz);
	avr_cycle_timer_register(e->avr, (avr_cycle_count_t)((double)EMU_FREQUENCY_HZ / (2.0 * c->hz)),
				 vtof_edge, e);
}

static void step_hook(struct avr_irq_t *irq, uint32_t value, void *param)
{
	(void)irq;
	struct emu *e = param;
	int level = value ? 1 : 0;
	int rising = level && !e->step_level;
	e->step_level = level;
	if (!rising)
		return;
	if (e->z_en_level) { /* ENA- high: the driver is disabled and ignores steps */
		e->steps_ignored++;
		return;
	}
	e->z_steps += e->dir_level ? 1 : -1;
	board_apply_inputs(e, 0);
}

static void dir_hook(struct avr_irq_t *irq, uint32_t value, void *param)
{
	(void)irq;
	((struct emu *)param)->dir_level = value ? 1 : 0;
}

static void torch_hook(struct avr_irq_t *irq, uint32_t value, void *param)
{
	(void)irq;
	struct emu *e = param;
	int level = value ? 1 : 0;
	if (level == e->torch_level)
		return;
	e->torch_level = level;
	uint64_t t = board_us(e);
	record_event(e, "torch", "%d", level);
	plant_torch(e, level, t);
	board_apply_inputs(e, 0);
}

static void ohmic_en_hook(struct avr_irq_t *irq, uint32_t value, void *param)
{
	(void)irq;
	struct emu *e = param;
	int level = value ? 1 : 0;
	if (level == e->ohmic_en_level)
		return;
	e->ohmic_en_level = level;
	record_event(e, "ohmic_enable", "%d", level);
	board_apply_inputs(e, 0);
}

static void z_en_hook(struct avr_irq_t *irq, uint32_t value, void *param)
{
	(void)irq;
	struct emu *e = param;
	int level = value ? 1 : 0;
	if (level == e->z_en_level)
		return;
	e->z_en_level = level;
	record_event(e, "z_enable_pin", "%d", level);
}

static avr_ioport_t *port_of(struct emu *e, char letter)
{
	int i = letter - 'A';
	if (i < 0 || i >= (int)(sizeof e->ports / sizeof e->ports[0]))
		return NULL;
	return (avr_ioport_t *)e->ports[i];
}

static int bind_pin(struct emu *e, struct pin_ref *ref, struct pin_map map, const char *what)
{
	ref->port = map.port;
	ref->bit = map.bit;
	ref->irq = avr_io_getirq(e->avr, AVR_IOCTL_IOPORT_GETIRQ(map.port), map.bit);
	if (!ref->irq || !port_of(e, map.port)) {
		fprintf(stderr, "dthc-emulated-board-host: no pin %c%d (%s) on %s\n", map.port,
			map.bit, what, e->mcu);
		return -1;
	}
	return 0;
}

static void find_ios(struct emu *e)
{
	for (avr_io_t *io = e->avr->io_port; io; io = io->next) {
		if (!strcmp(io->kind, "uart") && ((avr_uart_t *)io)->name == '0')
			e->uart = io;
		if (!strcmp(io->kind, "port")) {
			avr_ioport_t *p = (avr_ioport_t *)io;
			int i = p->name - 'A';
			if (i >= 0 && i < (int)(sizeof e->ports / sizeof e->ports[0]))
				e->ports[i] = p;
		}
	}
}

static void set_uart_flags(struct emu *e)
{
	uint32_t flags = 0;
	avr_ioctl(e->avr, AVR_IOCTL_UART_GET_FLAGS('0'), &flags);
	/* POLL_SLEEP: simavr would usleep on every idle status read (1000x slower);
	 * STDIO: it would print the board's bytes on our stdout. */
	flags &= ~(uint32_t)(AVR_UART_FLAG_POLL_SLEEP | AVR_UART_FLAG_STDIO);
	avr_ioctl(e->avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
	e->uart_flags = flags;
}

/*
 * An AVR keeps an interrupt's flag set while its enable bit is clear, and takes the
 * interrupt as soon as the bit is set again. simavr does not: a flag raised while masked
 * is never made pending when the mask is lifted (and a pending one masked is dropped), so a
 * firmware that masks its timer compare for a moment loses the tick (and, in normal mode,
 * waits a whole timer wrap for the next match). This write hook on the plain enable
 * registers (TIMSKn, EIMSK, PCICR: those no simavr module watches) restores the hardware
 * rule: when an enable bit goes 1 with its flag set, the interrupt is raised again.
 */
static void enable_write_hook(struct avr_t *avr, avr_io_addr_t addr, uint8_t v, void *param)
{
	(void)param;
	uint8_t before = avr->data[addr];
	avr_core_watch_write(avr, addr, v);
	uint8_t rising = (uint8_t)(v & ~before);
	if (!rising)
		return;
	avr_int_table_p table = &avr->interrupts;
	for (int i = 0; i < table->vector_count; i++) {
		avr_int_vector_t *vec = table->vector[i];
		if (vec->enable.reg != addr || !(rising & (vec->enable.mask << vec->enable.bit)))
			continue;
		if (vec->raised.reg && avr_regbit_get(avr, vec->raised) && !vec->pending)
			avr_raise_interrupt(avr, vec);
	}
}

static void hook_enable_registers(struct emu *e)
{
	avr_t *avr = e->avr;
	avr_int_table_p table = &avr->interrupts;
	for (int i = 0; i < table->vector_count; i++) {
		avr_io_addr_t reg = table->vector[i]->enable.reg;
		if (reg < 32 || AVR_DATA_TO_IO(reg) >= MAX_IOs)
			continue;
		if (avr->io[AVR_DATA_TO_IO(reg)].w.c) /* a module's register, or already hooked */
			continue;
		avr_register_io_write(avr, reg, enable_write_hook, e);
	}
}

/*
 * simavr polls an external interrupt pin in "strict level" mode while it is LOW (an ioctl
 * walking every module, each few cycles) even with the interrupt disabled; on the 328P
 * STEP and DIR are INT0/INT1 (PD2/PD3) and sit LOW, which cost 5x the CPU. Our outputs are
 * never interrupt inputs, so their INTs drop to edge-only level handling.
 */
static void relax_output_extints(struct emu *e)
{
	avr_extint_t *ext = NULL;
	for (avr_io_t *io = e->avr->io_port; io; io = io->next)
		if (!strcmp(io->kind, "extint"))
			ext = (avr_extint_t *)io;
	if (!ext)
		return;
	const struct pin_ref *outs[] = {&e->step, &e->dir, &e->torch, &e->ohmic_en, &e->z_en};
	for (int i = 0; i < EXTINT_COUNT; i++) {
		if (!ext->eint[i].port_ioctl)
			continue;
		char port = (char)(ext->eint[i].port_ioctl & 0xFF);
		for (size_t k = 0; k < sizeof outs / sizeof outs[0]; k++)
			if (outs[k]->port == port && outs[k]->bit == ext->eint[i].port_pin)
				avr_extint_set_strict_lvl_trig(e->avr, (uint8_t)i, 0);
	}
}

static void no_sleep(avr_t *avr, avr_cycle_count_t how_long)
{
	(void)avr;
	(void)how_long; /* the host paces simulated time to the wall clock itself */
}

static struct emu *the_emu; /* one board per process: simavr's reset hook has no param */

/* Wraps the core's reset hook: a reset simavr makes by itself (the watchdog) must get the
 * same fix-ups as ours (pins re-driven, relay seen off, inputs written back). */
static void reset_hook(avr_t *avr)
{
	if (the_emu->core_reset)
		the_emu->core_reset(avr);
	the_emu->reset_seen = 1;
}

static void after_reset(struct emu *e, const char *why);

int hex_nibble(int c)
{
	if (c >= '0' && c <= '9')
		return c - '0';
	if (c >= 'A' && c <= 'F')
		return c - 'A' + 10;
	if (c >= 'a' && c <= 'f')
		return c - 'a' + 10;
	return -1;
}

/* Intel HEX into flash at its addresses (records 00 data, 01 end, 02 and 04 address bases;
 * 03 and 05, start addresses, mean nothing to an AVR and are skipped: simavr's own reader
 * refuses 03, which Arduino's optiboot HEX carries). Every checksum is checked. The lowest
 * address written in *lowest (may be NULL). */
static int load_hex(struct emu *e, const char *path, uint32_t *lowest)
{
	FILE *f = fopen(path, "r");
	if (!f) {
		fprintf(stderr, "dthc-emulated-board-host: cannot read %s: %s\n", path,
			strerror(errno));
		return -1;
	}
	char line[600];
	uint32_t base = 0, low = UINT32_MAX;
	int lineno = 0, done = 0, bad = 0;
	while (!done && !bad && fgets(line, sizeof line, f)) {
		lineno++;
		size_t len = strcspn(line, "\r\n");
		if (len == 0)
			continue;
		uint8_t rec[264];
		size_t n = 0;
		if (line[0] != ':' || (len - 1) % 2 || (len - 1) / 2 > sizeof rec || len < 11) {
			bad = 1;
			break;
		}
		uint8_t sum = 0;
		for (size_t k = 1; k < len; k += 2) { /* len - 1 is even */
			int hi = hex_nibble(line[k]), lo = hex_nibble(line[k + 1]);
			if (hi < 0 || lo < 0) {
				bad = 1;
				break;
			}
			rec[n] = (uint8_t)(hi << 4 | lo);
			sum = (uint8_t)(sum + rec[n]);
			n++;
		}
		if (bad || sum != 0 || n != (size_t)rec[0] + 5) {
			bad = 1;
			break;
		}
		uint32_t count = rec[0], offset = (uint32_t)rec[1] << 8 | rec[2];
		const uint8_t *data = rec + 4;
		switch (rec[3]) {
		case 0x00: {
			uint32_t at = base + offset;
			if ((uint64_t)at + count > (uint64_t)e->avr->flashend + 1) {
				fprintf(stderr, "dthc-emulated-board-host: %s:%d: address 0x%x is beyond "
					"the %s's flash\n", path, lineno, (unsigned)at, e->mcu);
				fclose(f);
				return -1;
			}
			memcpy(e->avr->flash + at, data, count);
			if (count && at < low)
				low = at;
			break;
		}
		case 0x01: done = 1; break;
		case 0x02: base = ((uint32_t)data[0] << 8 | data[1]) << 4; break;
		case 0x04: base = ((uint32_t)data[0] << 8 | data[1]) << 16; break;
		case 0x03:
		case 0x05: break;
		default: bad = 1; break;
		}
	}
	fclose(f);
	if (bad || !done || low == UINT32_MAX) {
		fprintf(stderr, "dthc-emulated-board-host: %s:%d: not an Intel HEX image\n", path,
			lineno);
		return -1;
	}
	if (lowest)
		*lowest = low;
	return 0;
}

int board_init(struct emu *e)
{
	elf_firmware_t fw;
	memset(&fw, 0, sizeof fw);
	if (e->elf_path) {
		if (access(e->elf_path, R_OK) != 0) {
			fprintf(stderr, "dthc-emulated-board-host: cannot read the firmware ELF %s\n",
				e->elf_path);
			return -1;
		}
		if (elf_read_firmware(e->elf_path, &fw) != 0) {
			fprintf(stderr,
				"dthc-emulated-board-host: %s is not a firmware ELF simavr can load\n",
				e->elf_path);
			return -1;
		}
		if (fw.mmcu[0] && strcmp(fw.mmcu, e->mcu) != 0)
			fprintf(stderr,
				"dthc-emulated-board-host: warning: the ELF says mcu %s, running %s\n",
				fw.mmcu, e->mcu);
	}
	e->avr = avr_make_mcu_by_name(e->mcu);
	if (!e->avr) {
		fprintf(stderr, "dthc-emulated-board-host: simavr does not know mcu %s\n", e->mcu);
		return -1;
	}
	avr_init(e->avr);
	if (e->elf_path) {
		fw.frequency = EMU_FREQUENCY_HZ;
		fw.vcc = fw.avcc = fw.aref = (uint32_t)e->pins->adc_ref_mv;
		avr_load_firmware(e->avr, &fw);
	} else {
		/* A board as its bootloader was burned: the application's flash erased, unless
		 * --flash puts one there (as avrdude left it). */
		memset(e->avr->flash, 0xFF, e->avr->flashend + 1);
		if (e->flash_path && load_hex(e, e->flash_path, NULL))
			return -1;
	}
	if (e->bootloader_path) {
		/* The BOOTRST fuse: every reset starts at the boot section, where the HEX sits;
		 * the whole flash is code (the bootloader jumps to 0, the application may be
		 * anywhere below it). */
		uint32_t boot = 0;
		if (load_hex(e, e->bootloader_path, &boot))
			return -1;
		e->avr->reset_pc = boot;
		e->avr->pc = boot;
		e->avr->codeend = e->avr->flashend;
	}
	e->avr->frequency = EMU_FREQUENCY_HZ;
	e->avr->vcc = e->avr->avcc = e->avr->aref = (uint32_t)e->pins->adc_ref_mv;
	e->avr->sleep = no_sleep;
	e->avr->log = 1; /* warnings only */
	the_emu = e;
	e->core_reset = e->avr->reset;
	e->avr->reset = reset_hook;
	hook_enable_registers(e);

	find_ios(e);
	if (!e->uart) {
		fprintf(stderr, "dthc-emulated-board-host: %s has no UART0 in simavr\n", e->mcu);
		return -1;
	}
	set_uart_flags(e);
	e->uart_in = avr_io_getirq(e->avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
	avr_irq_register_notify(avr_io_getirq(e->avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT),
				uart_out_hook, e);
	avr_irq_register_notify(avr_io_getirq(e->avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF),
				uart_xoff_hook, e);
	avr_irq_register_notify(avr_io_getirq(e->avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON),
				uart_xon_hook, e);
	e->adc_irq = avr_io_getirq(e->avr, AVR_IOCTL_ADC_GETIRQ, 0);
	if (!e->adc_irq) {
		fprintf(stderr, "dthc-emulated-board-host: %s has no ADC in simavr\n", e->mcu);
		return -1;
	}
	avr_irq_register_notify(e->adc_irq + ADC_IRQ_OUT_TRIGGER, adc_trigger_hook, e);

	const struct board_pins *p = e->pins;
	if (bind_pin(e, &e->step, p->step, "STEP") || bind_pin(e, &e->dir, p->dir, "DIR") ||
	    bind_pin(e, &e->torch, p->torch, "TORCH") ||
	    bind_pin(e, &e->ohmic_en, p->ohmic_en, "OHMIC_ENABLE") ||
	    bind_pin(e, &e->z_en, p->z_en, "Z_ENABLE"))
		return -1;
	for (int i = 0; i < IN_COUNT; i++) {
		e->in_present[i] = p->in[i].port != 0;
		if (e->in_present[i] && bind_pin(e, &e->in_pins[i], p->in[i], input_name(i)))
			return -1;
	}
	if (e->arc_input == ARC_INPUT_VTOF) {
		if (!p->arc_vtof.port) {
			fprintf(stderr, "dthc-emulated-board-host: --arc-input vtof: the %s build has no "
				"V-to-F input (its T1 pin is OHMIC); the Mega 2560's is T5\n", e->mcu);
			return -1;
		}
		if (bind_pin(e, &e->arc_vtof, p->arc_vtof, "ARC_VTOF (T5)"))
			return -1;
	}
	relax_output_extints(e);
	avr_irq_register_notify(e->step.irq, step_hook, e);
	avr_irq_register_notify(e->dir.irq, dir_hook, e);
	avr_irq_register_notify(e->torch.irq, torch_hook, e);
	avr_irq_register_notify(e->ohmic_en.irq, ohmic_en_hook, e);
	avr_irq_register_notify(e->z_en.irq, z_en_hook, e);
	e->z_steps = (int64_t)p->z_boot_um * p->steps_per_mm / 1000;
	e->last_raw_cycle = e->avr->cycle;
	e->avr->data[MCUSR_ADDR] = MCUSR_PORF;
	board_apply_inputs(e, 1);
	vtof_arm(e);
	return 0;
}

/* The model's (or the forced) level of each input, pushed onto the pins; force_all also
 * rewrites the PIN bits (after a reset simavr clears them behind the pins' IRQ values). */
void board_apply_inputs(struct emu *e, int force_all)
{
	uint64_t t = board_us(e);
	plant_update(e, t);
	double z = board_z_mm(e);
	double surface = plant_surface_mm(e, t);
	int model[IN_COUNT] = {0};
	model[IN_ARC_OK] = e->arc.state == ARC_TRANSFERRED;
	model[IN_FLOAT] = z <= surface - e->p.float_travel_mm + 1e-9;
	model[IN_OHMIC] = z <= surface + 1e-9 && e->ohmic_en_level;
	model[IN_Z_LIMIT_MAX] = z >= e->p.home_switch_mm - 1e-9; /* the home switch */
	uint8_t mask[12] = {0}, value[12] = {0};
	for (int i = 0; i < IN_COUNT; i++) {
		if (!e->in_present[i])
			continue;
		int active = e->in_force[i] == FORCE_AUTO ? model[i] : e->in_force[i];
		int pi = e->in_pins[i].port - 'A';
		uint8_t bit = (uint8_t)(1u << e->in_pins[i].bit);
		mask[pi] |= bit;
		if (!active)
			value[pi] |= bit; /* inactive = pulled up HIGH; active = pulled LOW */
		if (active != e->in_level[i] || force_all) {
			if (active != e->in_level[i])
				record_event(e, "input", "%s,%d", input_name(i), active);
			e->in_level[i] = active;
		}
	}
	for (int pi = 0; pi < 12; pi++) {
		if (!mask[pi])
			continue;
		avr_ioport_t *port = (avr_ioport_t *)e->ports[pi];
		if (port->external.pull_mask != mask[pi] || port->external.pull_value != value[pi]) {
			avr_ioport_external_t ext = {
				.name = (unsigned long)('A' + pi), .mask = mask[pi], .value = value[pi]};
			avr_ioctl(e->avr, AVR_IOCTL_IOPORT_SET_EXTERNAL('A' + pi), &ext);
		}
		if (force_all)
			e->avr->data[port->r_pin] =
				(uint8_t)((e->avr->data[port->r_pin] & ~mask[pi]) | value[pi]);
	}
	for (int i = 0; i < IN_COUNT; i++) {
		if (!e->in_present[i])
			continue;
		uint32_t level = e->in_level[i] ? 0u : 1u;
		if (e->in_pins[i].irq->value != level || force_all)
			avr_raise_irq(e->in_pins[i].irq, level);
	}
}

static void reset_as(struct emu *e, uint8_t mcusr, const char *why)
{
	uint64_t before = e->avr->cycle;
	avr_reset(e->avr);
	uint64_t after = e->avr->cycle;
	e->cycle_base += before - after;
	e->last_raw_cycle = after;
	e->avr->state = cpu_Running;
	e->avr->data[MCUSR_ADDR] = mcusr;
	after_reset(e, why);
}

void board_reset(struct emu *e, int power_on)
{
	reset_as(e, power_on ? MCUSR_PORF : MCUSR_EXTRF, power_on ? "power_on" : "external_reset");
}

/* The port was opened: DTR pulls RESET low through the capacitor (the auto-reset), an
 * external reset as the button's. */
void board_auto_reset(struct emu *e)
{
	e->auto_resets++;
	reset_as(e, MCUSR_EXTRF, "auto_reset");
}

/* After any reset: simavr cleared the I/O registers behind the pins' IRQ values. */
static void after_reset(struct emu *e, const char *why)
{
	e->reset_seen = 0;
	set_uart_flags(e);
	relax_output_extints(e);
	e->reboots++;
	record_event(e, "reboot", "%s", why);
	/* Pins are inputs after a reset: the relay driver, STEP and ENA- see no drive. */
	avr_raise_irq(e->torch.irq, 0);
	avr_raise_irq(e->ohmic_en.irq, 0);
	avr_raise_irq(e->step.irq, 0);
	avr_raise_irq(e->dir.irq, 0);
	avr_raise_irq(e->z_en.irq, 0);
	if (e->rx_len) {
		record_event(e, "rx_dropped", "%zu,reset", e->rx_len);
		e->rx_dropped += e->rx_len;
	}
	e->rx_len = e->rx_head = 0;
	e->rx_frame.len = e->rx_frame.raw_len = 0;
	e->tx_frame.len = e->tx_frame.raw_len = 0;
	e->xoff = 0;
	e->rx_next_cycle = board_cycles(e);
	board_apply_inputs(e, 1);
	vtof_arm(e); /* simavr's reset cleared the cycle timers */
}

/* Run the core until the absolute cycle count end_cycles (a sleeping core may pass it by a
 * few cycles). Returns with e->avr->state telling whether the firmware still runs. */
void board_run_until(struct emu *e, uint64_t end_cycles)
{
	avr_t *avr = e->avr;
	wake_at(e, end_cycles, &wake_slice_tag);
	sync_uart_timing(e);
	for (;;) {
		uint64_t raw = avr->cycle;
		if (raw < e->last_raw_cycle) /* simavr restarted its counter (a watchdog reset) */
			e->cycle_base += e->last_raw_cycle - raw;
		e->last_raw_cycle = raw;
		uint64_t now = e->cycle_base + raw;
		if (now >= end_cycles)
			break;
		if (e->rx_len && now >= e->rx_next_cycle)
			deliver_rx(e);
		int state = avr_run(avr);
		if (e->reset_seen) { /* the watchdog (or the firmware) reset the MCU */
			uint64_t raw_now = avr->cycle;
			if (raw_now < e->last_raw_cycle)
				e->cycle_base += e->last_raw_cycle - raw_now;
			e->last_raw_cycle = raw_now;
			after_reset(e, "internal");
		}
		if (state != cpu_Running && state != cpu_Sleeping)
			break;
	}
}
