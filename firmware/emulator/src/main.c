/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * main.c - dthc-emulated-board-host: options, signals and the paced run loop.
 *
 * One thread: the core runs in slices of SLICE_US simulated microseconds while simulated
 * time is behind the wall clock; between slices the pty and stdin are polled, the inputs
 * updated and the board's bytes written. Ahead of the wall clock, the loop waits in ppoll
 * for exactly the time needed, woken early by host bytes. Behind it (a loaded machine) it
 * runs flat out to catch up; more than MAX_LAG_S behind, it re-anchors and records a lag.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <getopt.h>
#include <poll.h>
#include <signal.h>
#include <stdlib.h>
#include <string.h>
#include <sys/prctl.h>
#include <time.h>
#include <termios.h>
#include <unistd.h>

#include "host.h"

#define SLICE_US 100
#define MAX_LAG_S 1.0
#define PARENT_CHECK_S 0.1
#define Z_RECORD_US 10000
#define READY_AFTER_US 200000 /* READY at the latest this long after power-on */

volatile int emu_stop;
volatile int emu_reboot;

static void on_stop(int sig)
{
	(void)sig;
	emu_stop = 1;
}

static void on_reboot(int sig)
{
	(void)sig;
	emu_reboot = 1;
}

static void usage(FILE *f)
{
	fprintf(f,
		"usage: dthc-emulated-board-host --elf FILE --pty PATH [--mcu atmega2560|atmega328p]\n"
		"       (or --bootloader HEX [--flash HEX] instead of --elf: Arduino's bootloader at\n"
		"       the top of flash, the application from HEX or erased, auto-reset on open)\n"
		"       [--record FILE] [--seed N] [--plate-mm Z] [--warp-mm A --warp-period-s P]\n"
		"       [--arc-slope-v-mm S] [--cut-v V] [--cut-height-mm H] [--noise-v SIGMA]\n"
		"       [--arc-ok-delay-ms MS] [--float-travel-mm MM] [--ocv-v V]\n"
		"       [--transfer-max-mm MM] [--lose-above-mm MM] [--pilot-timeout-ms MS]\n"
		"       [--speed FACTOR (simulated per wall second; 0: flat out, for benchmarks)]\n"
		"       [--arc-input adc|vtof] [--vtof-zero-hz HZ] [--vtof-full-hz HZ] [--vtof-full-v V]\n"
		"Runs a firmware ELF on simavr at 16 MHz, UART0 on a pty symlinked at PATH, paced to\n"
		"the wall clock. Control commands on stdin (help: firmware/emulator/README.md).\n"
		"SIGUSR2 resets the MCU (external reset); SIGTERM/SIGINT exit.\n");
}

enum {
	OPT_ELF = 1000, OPT_PTY, OPT_MCU, OPT_RECORD, OPT_SEED, OPT_PLATE, OPT_WARP,
	OPT_WARP_PERIOD, OPT_SLOPE, OPT_CUT_V, OPT_CUT_H, OPT_NOISE, OPT_ARC_OK_DELAY,
	OPT_FLOAT_TRAVEL, OPT_OCV, OPT_TRANSFER_MAX, OPT_LOSE_ABOVE, OPT_PILOT_TIMEOUT, OPT_HELP,
	OPT_SPEED, OPT_ARC_INPUT, OPT_VTOF_ZERO, OPT_VTOF_FULL, OPT_VTOF_FULL_V, OPT_BOOTLOADER,
	OPT_FLASH, OPT_HOME_SWITCH,
};

static const struct option long_opts[] = {
	{"elf", required_argument, 0, OPT_ELF},
	{"bootloader", required_argument, 0, OPT_BOOTLOADER},
	{"flash", required_argument, 0, OPT_FLASH},
	{"pty", required_argument, 0, OPT_PTY},
	{"mcu", required_argument, 0, OPT_MCU},
	{"record", required_argument, 0, OPT_RECORD},
	{"seed", required_argument, 0, OPT_SEED},
	{"plate-mm", required_argument, 0, OPT_PLATE},
	{"warp-mm", required_argument, 0, OPT_WARP},
	{"warp-period-s", required_argument, 0, OPT_WARP_PERIOD},
	{"arc-slope-v-mm", required_argument, 0, OPT_SLOPE},
	{"cut-v", required_argument, 0, OPT_CUT_V},
	{"cut-height-mm", required_argument, 0, OPT_CUT_H},
	{"noise-v", required_argument, 0, OPT_NOISE},
	{"arc-ok-delay-ms", required_argument, 0, OPT_ARC_OK_DELAY},
	{"float-travel-mm", required_argument, 0, OPT_FLOAT_TRAVEL},
	{"ocv-v", required_argument, 0, OPT_OCV},
	{"transfer-max-mm", required_argument, 0, OPT_TRANSFER_MAX},
	{"lose-above-mm", required_argument, 0, OPT_LOSE_ABOVE},
	{"pilot-timeout-ms", required_argument, 0, OPT_PILOT_TIMEOUT},
	{"home-switch-mm", required_argument, 0, OPT_HOME_SWITCH},
	{"speed", required_argument, 0, OPT_SPEED},
	{"arc-input", required_argument, 0, OPT_ARC_INPUT},
	{"vtof-zero-hz", required_argument, 0, OPT_VTOF_ZERO},
	{"vtof-full-hz", required_argument, 0, OPT_VTOF_FULL},
	{"vtof-full-v", required_argument, 0, OPT_VTOF_FULL_V},
	{"help", no_argument, 0, OPT_HELP},
	{0, 0, 0, 0},
};

static int number(const char *opt, const char *s, double *out)
{
	char *end;
	errno = 0;
	double v = strtod(s, &end);
	if (errno || end == s || *end) {
		fprintf(stderr, "dthc-emulated-board-host: --%s: '%s' is not a number\n", opt, s);
		return -1;
	}
	*out = v;
	return 0;
}

static int parse_args(struct emu *e, int argc, char **argv)
{
	struct model_params *p = &e->p;
	*p = (struct model_params){
		.plate_mm = 20.0,
		.warp_mm = 0.0,
		.warp_period_s = 0.0,
		.arc_slope_v_mm = 7.5,
		.cut_v = 116.0,
		.cut_height_mm = 1.5,
		.noise_v = 0.4,
		.arc_ok_delay_ms = 100.0,
		.ocv_v = 250.0,
		.transfer_max_mm = 8.0,
		.lose_above_mm = 10.0,
		.pilot_timeout_ms = 3000.0,
		.float_travel_mm = 1.5,
		.home_switch_mm = 102.0, /* the reference firmware's DTHC_Z_HOME_UM */
	};
	e->mcu = "atmega2560";
	e->seed = 1;
	e->arc_input = ARC_INPUT_ADC;
	e->vtof.zero_hz = 121000.0;
	e->vtof.full_hz = 925000.0;
	e->vtof.full_v = 10.0;
	e->speed = 1.0;
	int c;
	while ((c = getopt_long(argc, argv, "", long_opts, NULL)) != -1) {
		double v = 0;
		const char *name = NULL;
		double *target = NULL;
		switch (c) {
		case OPT_ELF: e->elf_path = optarg; continue;
		case OPT_BOOTLOADER: e->bootloader_path = optarg; continue;
		case OPT_FLASH: e->flash_path = optarg; continue;
		case OPT_PTY: e->pty_path = optarg; continue;
		case OPT_MCU: e->mcu = optarg; continue;
		case OPT_RECORD: e->record_path = optarg; continue;
		case OPT_HELP: usage(stdout); exit(0);
		case OPT_SPEED:
			if (number("speed", optarg, &e->speed) || e->speed < 0.0) {
				fprintf(stderr, "dthc-emulated-board-host: --speed: a factor >= 0\n");
				return -1;
			}
			continue;
		case OPT_ARC_INPUT:
			if (!strcmp(optarg, "adc"))
				e->arc_input = ARC_INPUT_ADC;
			else if (!strcmp(optarg, "vtof"))
				e->arc_input = ARC_INPUT_VTOF;
			else {
				fprintf(stderr, "dthc-emulated-board-host: --arc-input %s: adc or vtof\n",
					optarg);
				return -1;
			}
			continue;
		case OPT_VTOF_ZERO: name = "vtof-zero-hz"; target = &e->vtof.zero_hz; break;
		case OPT_VTOF_FULL: name = "vtof-full-hz"; target = &e->vtof.full_hz; break;
		case OPT_VTOF_FULL_V: name = "vtof-full-v"; target = &e->vtof.full_v; break;
		case OPT_SEED:
			if (number("seed", optarg, &v))
				return -1;
			e->seed = (uint64_t)v;
			continue;
		case OPT_PLATE: name = "plate-mm"; target = &p->plate_mm; break;
		case OPT_WARP: name = "warp-mm"; target = &p->warp_mm; break;
		case OPT_WARP_PERIOD: name = "warp-period-s"; target = &p->warp_period_s; break;
		case OPT_SLOPE: name = "arc-slope-v-mm"; target = &p->arc_slope_v_mm; break;
		case OPT_CUT_V: name = "cut-v"; target = &p->cut_v; break;
		case OPT_CUT_H: name = "cut-height-mm"; target = &p->cut_height_mm; break;
		case OPT_NOISE: name = "noise-v"; target = &p->noise_v; break;
		case OPT_ARC_OK_DELAY: name = "arc-ok-delay-ms"; target = &p->arc_ok_delay_ms; break;
		case OPT_FLOAT_TRAVEL: name = "float-travel-mm"; target = &p->float_travel_mm; break;
		case OPT_OCV: name = "ocv-v"; target = &p->ocv_v; break;
		case OPT_TRANSFER_MAX: name = "transfer-max-mm"; target = &p->transfer_max_mm; break;
		case OPT_LOSE_ABOVE: name = "lose-above-mm"; target = &p->lose_above_mm; break;
		case OPT_PILOT_TIMEOUT: name = "pilot-timeout-ms"; target = &p->pilot_timeout_ms; break;
		case OPT_HOME_SWITCH: name = "home-switch-mm"; target = &p->home_switch_mm; break;
		default: usage(stderr); return -1;
		}
		if (number(name, optarg, target))
			return -1;
	}
	if (optind < argc) {
		fprintf(stderr, "dthc-emulated-board-host: unexpected argument '%s'\n", argv[optind]);
		return -1;
	}
	if (!e->pty_path || (!e->elf_path && !e->bootloader_path)) {
		fprintf(stderr, "dthc-emulated-board-host: --pty and --elf (or --bootloader) are "
				"required\n");
		usage(stderr);
		return -1;
	}
	if (e->bootloader_path && e->elf_path) {
		fprintf(stderr, "dthc-emulated-board-host: --bootloader loads the application with "
				"--flash HEX (or none: erased), not --elf\n");
		return -1;
	}
	if (e->flash_path && !e->bootloader_path) {
		fprintf(stderr, "dthc-emulated-board-host: --flash needs --bootloader\n");
		return -1;
	}
	if (!strcmp(e->mcu, "atmega2560"))
		e->pins = &pinmap_atmega2560;
	else if (!strcmp(e->mcu, "atmega328p"))
		e->pins = &pinmap_atmega328p;
	else {
		fprintf(stderr, "dthc-emulated-board-host: --mcu %s: atmega2560 or atmega328p\n",
			e->mcu);
		return -1;
	}
	if (!(e->vtof.zero_hz > 0.0) || !(e->vtof.full_hz > e->vtof.zero_hz) ||
	    e->vtof.full_hz > 4000000.0 || !(e->vtof.full_v > 0.0)) {
		fprintf(stderr, "dthc-emulated-board-host: the V-to-F card needs 0 < --vtof-zero-hz "
				"< --vtof-full-hz <= 4 MHz and --vtof-full-v > 0\n");
		return -1;
	}
	if (p->warp_mm != 0.0 && p->warp_period_s <= 0.0) {
		fprintf(stderr, "dthc-emulated-board-host: --warp-mm needs --warp-period-s > 0\n");
		return -1;
	}
	return 0;
}

static void read_pty(struct emu *e)
{
	uint8_t buf[4096];
	for (;;) {
		ssize_t n = read(e->master_fd, buf, sizeof buf);
		if (n <= 0)
			return;
		board_queue_rx(e, buf, (size_t)n);
	}
}

/* A client opened the port (--bootloader): what the board sent while the port was closed
 * never reached a closed tty, so it is discarded (the pty's and ours), then the MCU resets
 * as DTR makes it. */
static void auto_reset(struct emu *e)
{
	tcflush(e->slave_fd, TCIFLUSH);
	e->tx_len = 0;
	board_auto_reset(e);
}

static void say_ready(struct emu *e)
{
	if (e->ready)
		return;
	e->ready = 1;
	record_event(e, "ready", "%s", e->pty_path);
	fprintf(e->out, "READY %s\n", e->pty_path);
	fflush(e->out);
}

static int run(struct emu *e)
{
	const uint64_t slice = SLICE_US * EMU_CYCLES_PER_US;
	pid_t parent = getppid();
	double next_parent_check = 0;
	double t0 = mono_s();
	uint64_t sim0 = board_cycles(e);
	e->wall_t0 = t0;
	struct pollfd pfd[3] = {{.fd = e->master_fd, .events = POLLIN},
				{.fd = 0, .events = POLLIN},
				{.fd = e->open_watch_fd, .events = POLLIN}};
	unsigned slices = 0;
	while (!emu_stop) {
		if (emu_reboot) {
			emu_reboot = 0;
			board_reset(e, 0);
		}
		double now_s = mono_s();
		double target = e->speed > 0.0
					? (double)sim0 + (now_s - t0) * e->speed * (double)EMU_FREQUENCY_HZ
					: 1e30; /* --speed 0: flat out */
		uint64_t cycles = board_cycles(e);
		if ((double)cycles < target) {
			double lag_s = e->speed > 0.0 ? (target - (double)cycles) /
								(e->speed * (double)EMU_FREQUENCY_HZ)
						       : 0.0;
			if (lag_s > e->max_lag_s)
				e->max_lag_s = lag_s;
			if (lag_s > MAX_LAG_S) {
				record_event(e, "lag", "%.0f", lag_s * 1e6);
				e->lag_events++;
				t0 += lag_s; /* give up on the lost time: re-anchor */
			}
			board_run_until(e, cycles + slice);
			if (e->avr->state != cpu_Running && e->avr->state != cpu_Sleeping) {
				record_event(e, "stopped", "%d", e->avr->state);
				fprintf(stderr,
					"dthc-emulated-board-host: the firmware stopped (simavr state %d: %s)\n",
					e->avr->state,
					e->avr->state == cpu_Done ? "sleep with interrupts off"
								  : "crashed");
				return 3;
			}
			board_apply_inputs(e, 0);
			pty_flush_tx(e);
			/* Ahead of the wall clock, ppoll below wakes on host bytes at once; behind it
			 * (catching up), look for them every other slice. An open of the port first:
			 * what the opener writes reaches the MCU after its reset. */
			if (slices & 1) {
				if (pty_opened(e))
					auto_reset(e);
				read_pty(e);
			}
			uint64_t t = board_us(e);
			if (t >= e->next_z_record_us) {
				record_event(e, "z", "%lld",
					     (long long)(e->z_steps * 1000 / e->pins->steps_per_mm));
				e->next_z_record_us = t - t % Z_RECORD_US + Z_RECORD_US;
			}
			if (!e->ready && (board_rx_enabled(e) || t >= READY_AFTER_US))
				say_ready(e);
			if ((++slices & 15) == 0)
				control_poll(e);
		} else {
			double ahead_s =
				((double)cycles - target) / (e->speed * (double)EMU_FREQUENCY_HZ);
			struct timespec ts = {
				.tv_sec = (time_t)ahead_s,
				.tv_nsec = (long)((ahead_s - (double)(time_t)ahead_s) * 1e9)};
			pfd[1].fd = e->ctl_eof ? -1 : 0;
			int n = ppoll(pfd, 3, &ts, NULL);
			if (n > 0) {
				if ((pfd[2].revents & POLLIN) && pty_opened(e))
					auto_reset(e);
				if (pfd[0].revents & POLLIN)
					read_pty(e);
				if (pfd[1].revents)
					control_poll(e);
			}
		}
		if (now_s >= next_parent_check) {
			next_parent_check = now_s + PARENT_CHECK_S;
			if (getppid() != parent) {
				fprintf(stderr, "dthc-emulated-board-host: parent gone, exiting\n");
				break;
			}
		}
	}
	return 0;
}

int main(int argc, char **argv)
{
	static struct emu e;
	e.master_fd = e.slave_fd = e.open_watch_fd = -1;
	for (int i = 0; i < IN_COUNT; i++)
		e.in_force[i] = FORCE_AUTO;
	pid_t parent = getppid();
	prctl(PR_SET_PDEATHSIG, SIGTERM);
	if (getppid() != parent)
		return 1;
	if (parse_args(&e, argc, argv))
		return 2;
	/* Replies and READY go to the real stdout; simavr's own printf chatter to stderr. */
	int out_fd = dup(1);
	if (out_fd < 0 || dup2(2, 1) < 0 || !(e.out = fdopen(out_fd, "w"))) {
		perror("dthc-emulated-board-host: stdout");
		return 2;
	}
	struct sigaction sa;
	memset(&sa, 0, sizeof sa);
	sa.sa_handler = on_stop;
	sigaction(SIGTERM, &sa, NULL);
	sigaction(SIGINT, &sa, NULL);
	sigaction(SIGHUP, &sa, NULL);
	sa.sa_handler = on_reboot;
	sigaction(SIGUSR2, &sa, NULL);
	signal(SIGPIPE, SIG_IGN);

	plant_seed(&e);
	if (record_open(&e))
		return 2;
	if (board_init(&e))
		return 2;
	if (pty_open(&e)) {
		pty_close(&e);
		return 2;
	}
	record_event(&e, "start", "%s,%s,%s", e.mcu,
		     e.elf_path ? e.elf_path : e.flash_path ? e.flash_path : "erased", e.pty_name);
	int status = run(&e);
	record_event(&e, "exit", "%d", status);
	char buf[1024];
	control_status(&e, buf, sizeof buf);
	fprintf(stderr, "dthc-emulated-board-host: exit: %s\n", buf);
	pty_close(&e);
	record_close(&e);
	return status;
}
