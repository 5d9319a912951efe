/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * host.h - the emulated-board host: one firmware ELF on simavr, UART0 on a pty, a Z axis
 * counted from STEP/DIR, a plate and arc model driving the inputs and the arc ADC channel,
 * a control channel on stdin and an event record.
 *
 * Copyright the dthc-bridge authors. Links simavr (GPL-3.0-or-later), hence this licence:
 * see ../LICENSE.
 */
#ifndef DTHC_EMU_HOST_H
#define DTHC_EMU_HOST_H

#include <stdint.h>
#include <stdio.h>

#include "sim_avr.h"
#include "sim_irq.h"

#include "pinmap.h"

#define EMU_FREQUENCY_HZ 16000000UL
#define EMU_CYCLES_PER_US (EMU_FREQUENCY_HZ / 1000000UL)
#define EMU_RX_BUFFER 65536
#define EMU_TX_BUFFER 65536
#define EMU_FRAME_PEEK 8 /* decoded bytes of a frame kept for the record (type, seq, ...) */

/* The inputs, in protocol bit order (PROTOCOL.md §7). */
enum emu_input {
	IN_ARC_OK = 0,
	IN_OHMIC,
	IN_FLOAT,
	IN_BREAKAWAY,
	IN_THC_UP,
	IN_THC_DOWN,
	IN_ESTOP,
	IN_Z_LIMIT_MIN,
	IN_Z_LIMIT_MAX,
	IN_COUNT
};

enum emu_force { FORCE_AUTO = -1, FORCE_INACTIVE = 0, FORCE_ACTIVE = 1 };

enum arc_state { ARC_OFF = 0, ARC_PILOT, ARC_TRANSFERRED, ARC_LOST, ARC_NO_TRANSFER };

enum arc_input { ARC_INPUT_ADC = 0, ARC_INPUT_VTOF };

/* The voltage-to-frequency card (--arc-input vtof): a square wave on T5 whose frequency
 * follows the arc voltage, re-evaluated at each edge. */
struct vtof_card {
	double zero_hz;  /* at 0 V input */
	double full_hz;  /* at full_v */
	double full_v;   /* the card's full-scale input */
	int level;       /* the pin now */
	double next_edge; /* raw simavr cycles of the next edge (fractional: exact mean rate) */
	double hz;       /* the frequency now */
	double noise_v;  /* the arc noise held until noise_until_us */
	uint64_t noise_until_us;
	uint64_t edges;  /* rising edges driven */
};

/* Plate and arc model parameters (command line, some changeable at run time). */
struct model_params {
	double plate_mm;
	double warp_mm;
	double warp_period_s;
	double arc_slope_v_mm;
	double cut_v;
	double cut_height_mm;
	double noise_v;
	double arc_ok_delay_ms;
	double ocv_v;
	double transfer_max_mm;
	double lose_above_mm;
	double pilot_timeout_ms;
	double float_travel_mm;
	double home_switch_mm; /* Z_LIMIT_MAX closes at and above it (the home switch) */
};

#define VTOF_NOISE_HOLD_US 104 /* a fresh noise draw as often as the ADC converts */

struct arc_model {
	enum arc_state state;
	uint64_t on_us;       /* relay on (pilot start) */
	uint64_t transfer_us; /* transfer time */
	double last_v;
	uint64_t rng;
	int have_spare;
	double spare;
};

/* COBS frame peek: the first decoded bytes of a frame, for the record. */
struct frame_peek {
	uint8_t raw[EMU_FRAME_PEEK + 2];
	int raw_len;
	int len; /* encoded bytes so far */
	uint64_t start_us; /* simulated time of the frame's first byte */
};

struct pin_ref {
	char port;
	int bit;
	avr_irq_t *irq;
};

struct emu {
	/* options */
	const char *elf_path;      /* the application as an ELF; NULL with --bootloader */
	const char *flash_path;    /* --flash: the application as Intel HEX */
	const char *bootloader_path; /* --bootloader: Arduino's bootloader HEX, auto-reset on */
	const char *mcu;
	const char *pty_path;
	const char *record_path;
	struct model_params p;
	uint64_t seed;
	enum arc_input arc_input;
	struct vtof_card vtof;

	/* simulator */
	const struct board_pins *pins;
	avr_t *avr;
	void *uart; /* avr_uart_t *, found by walking the io ports */
	void *ports[12]; /* avr_ioport_t * by letter - 'A' */
	uint32_t uart_flags;
	avr_irq_t *uart_in;
	avr_irq_t *adc_irq; /* base of the ADC irqs */
	uint64_t cycle_base; /* cycles before the last reset (simavr may restart its counter) */
	uint64_t last_raw_cycle;
	int xoff;
	void (*core_reset)(struct avr_t *avr); /* the core's own reset hook, wrapped */
	int reset_seen; /* simavr reset the MCU (ours, or its watchdog's) */
	int resetting; /* inside board_reset */

	/* pins */
	struct pin_ref in_pins[IN_COUNT];
	int in_present[IN_COUNT];
	struct pin_ref step, dir, torch, ohmic_en, z_en, arc_vtof;
	int step_level, dir_level, torch_level, ohmic_en_level, z_en_level;

	/* physics */
	int64_t z_steps;
	uint64_t steps_ignored;
	int in_force[IN_COUNT];
	int in_level[IN_COUNT]; /* 1 = active (pin LOW) */
	struct arc_model arc;

	/* link */
	int master_fd;
	int slave_fd;
	int open_watch_fd; /* inotify IN_OPEN on the slave (--bootloader: auto-reset), or -1 */
	uint64_t auto_resets;
	char pty_name[128];
	uint8_t rx[EMU_RX_BUFFER];
	size_t rx_head, rx_len;
	uint64_t rx_next_cycle; /* absolute cycles: the earliest the next host byte may start */
	uint64_t rx_bytes, rx_dropped;
	struct frame_peek rx_frame;
	uint8_t tx[EMU_TX_BUFFER];
	size_t tx_len;
	uint64_t tx_bytes, tx_dropped;
	struct frame_peek tx_frame;

	/* record */
	FILE *record;
	uint64_t next_z_record_us;

	/* control */
	FILE *out;
	char ctl_line[512];
	size_t ctl_len;
	int ctl_eof;

	/* pacing */
	double speed; /* simulated seconds per wall second; 0: flat out */
	double wall_t0;
	uint64_t sim_t0_cycles;
	uint64_t lag_events;
	double max_lag_s;
	uint64_t reboots;
	int ready;
};

/* board.c */
int board_init(struct emu *e);
void board_reset(struct emu *e, int power_on);
void board_auto_reset(struct emu *e);
uint64_t board_cycles(struct emu *e);
uint64_t board_us(struct emu *e);
void board_run_until(struct emu *e, uint64_t end_cycles);
void board_apply_inputs(struct emu *e, int force_all);
void board_queue_rx(struct emu *e, const uint8_t *data, size_t n);
int board_rx_enabled(struct emu *e);
double board_z_mm(const struct emu *e);
double board_vtof_hz(struct emu *e, double arc_v);

/* plant.c */
double plant_surface_mm(const struct emu *e, uint64_t t_us);
double plant_arc_voltage(struct emu *e, uint64_t t_us);
double plant_arc_model_v(struct emu *e, uint64_t t_us);
double plant_noise(struct emu *e);
void plant_update(struct emu *e, uint64_t t_us);
void plant_torch(struct emu *e, int on, uint64_t t_us);
void plant_seed(struct emu *e);
const char *plant_arc_name(enum arc_state s);
const char *input_name(int i);

/* pty.c */
int pty_open(struct emu *e);
void pty_close(struct emu *e);
void pty_flush_tx(struct emu *e);
int pty_opened(struct emu *e);

/* board.c: a hex digit's value, -1 if it is none */
int hex_nibble(int c);

/* record.c */
int record_open(struct emu *e);
void record_link_drop(struct emu *e, double rate, double for_s); /* frame loss on the stream */
uint64_t record_frames_lost(void);
void record_event(struct emu *e, const char *event, const char *fmt, ...)
	__attribute__((format(printf, 3, 4)));
void record_close(struct emu *e);
void frame_byte(struct emu *e, struct frame_peek *f, uint8_t byte, const char *event);
double mono_s(void);

/* control.c */
void control_poll(struct emu *e);
void control_status(struct emu *e, char *buf, size_t n);

/* main.c */
extern volatile int emu_stop;
extern volatile int emu_reboot;

#endif
