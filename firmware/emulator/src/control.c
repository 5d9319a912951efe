/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * control.c - the control channel: one command per line on stdin, one reply line on
 * stdout ("ok", a status line, or "error: ..."). stdin EOF only stops the reading.
 *
 *   set INPUT 1|0|auto     force an input active / inactive, or give it back to the model
 *                          (arc_ok ohmic float breakaway thc_up thc_down estop z_limit_min
 *                          z_limit_max; auto = the model: z_limit_max is the home switch
 *                          at home-switch-mm, z_limit_min never active)
 *   plate MM               the plate's height
 *   warp A_MM PERIOD_S     the plate's warp under the moving torch (0 0: flat)
 *   model KEY VALUE        any model option by its command-line name (noise-v, cut-v, ...)
 *   z MM                   put the carriage at Z (a hand on the axis; the firmware is not told)
 *   status                 one line: sim time, Z, outputs, arc, inputs, counters
 *   peek ADDR N            N (1..4) bytes of data memory at ADDR (a variable's address from
 *                          avr-nm, less 0x800000), little-endian -> "peek VALUE" (decimal)
 *   reboot                 as SIGUSR2: reset the MCU (external reset), Z kept
 *   quit                   exit as on SIGTERM
 *
 * Link faults (the fault matrix, `dthc-bridge bench faults --board MCU`):
 *
 *   unplug                 the USB cable pulled: the pty's master is closed (its client reads
 *                          EIO, polls HUP) and the --pty link removed; the board runs on and
 *                          what it sends goes nowhere
 *   replug                 a new pty behind the same --pty path (as a re-enumerated port)
 *   inject HEX             these bytes (at most 240) into the board's stream to the host,
 *                          after what the firmware has queued: garbage on the line
 *   drop RATE SECONDS      lose each board frame whole with probability RATE for SECONDS
 *                          (record.c), the host's frames untouched
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <math.h>
#include <poll.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "host.h"


/* While unplugged: the write end of the pipe whose read end stands in for the pty's master
 * and slave descriptors (same numbers, so main.c's poll set stays valid: never readable,
 * reads EAGAIN, writes fail), or -1. */
static int unplug_hold = -1;

struct model_key {
	const char *name;
	size_t offset;
};

#define MK(n, f) {n, offsetof(struct model_params, f)}
static const struct model_key model_keys[] = {
	MK("plate-mm", plate_mm),
	MK("warp-mm", warp_mm),
	MK("warp-period-s", warp_period_s),
	MK("arc-slope-v-mm", arc_slope_v_mm),
	MK("cut-v", cut_v),
	MK("cut-height-mm", cut_height_mm),
	MK("noise-v", noise_v),
	MK("arc-ok-delay-ms", arc_ok_delay_ms),
	MK("ocv-v", ocv_v),
	MK("transfer-max-mm", transfer_max_mm),
	MK("lose-above-mm", lose_above_mm),
	MK("pilot-timeout-ms", pilot_timeout_ms),
	MK("float-travel-mm", float_travel_mm),
	MK("home-switch-mm", home_switch_mm),
};

static int parse_double(const char *s, double *out)
{
	if (!s)
		return -1;
	char *end;
	errno = 0;
	double v = strtod(s, &end);
	if (errno || end == s || *end || !isfinite(v))
		return -1;
	*out = v;
	return 0;
}

void control_status(struct emu *e, char *buf, size_t n)
{
	uint64_t t = board_us(e);
	int len = snprintf(
		buf, n,
		"status t_us=%llu wall_s=%.6f z_um=%lld plate_mm=%.4f surface_mm=%.4f torch=%d "
		"ohmic_enable=%d z_enable_pin=%d arc=%s arc_v=%.2f inputs=",
		(unsigned long long)t, mono_s() - e->wall_t0,
		(long long)llround(board_z_mm(e) * 1000.0), e->p.plate_mm, plant_surface_mm(e, t),
		e->torch_level, e->ohmic_en_level, e->z_en_level, plant_arc_name(e->arc.state),
		e->arc.last_v);
	const char *sep = "";
	for (int i = 0; i < IN_COUNT && len > 0 && (size_t)len < n; i++) {
		if (!e->in_present[i])
			continue;
		len += snprintf(buf + len, n - (size_t)len, "%s%s:%d%s", sep, input_name(i),
				e->in_level[i], e->in_force[i] == FORCE_AUTO ? "" : "!");
		sep = ",";
	}
	if (len > 0 && (size_t)len < n)
		snprintf(buf + len, n - (size_t)len,
			 " rx_bytes=%llu rx_dropped=%llu tx_bytes=%llu tx_dropped=%llu "
			 "steps_ignored=%llu reboots=%llu max_lag_ms=%.1f arc_input=%s vtof_hz=%.0f "
			 "vtof_edges=%llu link=%s frames_lost=%llu",
			 (unsigned long long)e->rx_bytes, (unsigned long long)e->rx_dropped,
			 (unsigned long long)e->tx_bytes, (unsigned long long)e->tx_dropped,
			 (unsigned long long)e->steps_ignored, (unsigned long long)e->reboots,
			 e->max_lag_s * 1000.0, e->arc_input == ARC_INPUT_VTOF ? "vtof" : "adc",
			 e->arc_input == ARC_INPUT_VTOF ? e->vtof.hz : 0.0,
			 (unsigned long long)e->vtof.edges, unplug_hold >= 0 ? "unplugged" : "up",
			 (unsigned long long)record_frames_lost());
}

/* Put descriptor `from` at number `to` (same open file, close-on-exec), closing `from`. */
static int move_fd(int from, int to)
{
	if (dup2(from, to) < 0)
		return -1;
	close(from);
	return fcntl(to, F_SETFD, FD_CLOEXEC);
}

static const char *link_unplug(struct emu *e)
{
	if (e->bootloader_path)
		return "error: unplug: not with --bootloader (the open watch is not re-armed)";
	if (unplug_hold >= 0)
		return "error: unplug: already unplugged";
	int p[2];
	if (pipe2(p, O_NONBLOCK | O_CLOEXEC) != 0)
		return "error: unplug: pipe failed";
	char target[PATH_MAX];
	ssize_t n = readlink(e->pty_path, target, sizeof target - 1);
	if (n > 0) {
		target[n] = 0;
		if (!strcmp(target, e->pty_name)) /* only our own link */
			unlink(e->pty_path);
	}
	/* The pty's last master descriptor closes here: its client sees the hang-up. */
	if (dup2(p[0], e->slave_fd) < 0 || move_fd(p[0], e->master_fd) != 0) {
		close(p[1]);
		return "error: unplug: dup2 failed";
	}
	fcntl(e->slave_fd, F_SETFD, FD_CLOEXEC);
	unplug_hold = p[1];
	e->tx_len = 0;
	record_event(e, "unplug", "%s", e->pty_name);
	return "ok";
}

static const char *link_replug(struct emu *e)
{
	if (unplug_hold < 0)
		return "error: replug: not unplugged";
	int old_master = e->master_fd, old_slave = e->slave_fd;
	if (pty_open(e) != 0) {
		if (e->master_fd >= 0 && e->master_fd != old_master)
			close(e->master_fd);
		if (e->slave_fd >= 0 && e->slave_fd != old_slave)
			close(e->slave_fd);
		e->master_fd = old_master;
		e->slave_fd = old_slave;
		return "error: replug: cannot open a new pty (see stderr)";
	}
	if (move_fd(e->master_fd, old_master) != 0 || move_fd(e->slave_fd, old_slave) != 0)
		return "error: replug: dup2 failed";
	e->master_fd = old_master;
	e->slave_fd = old_slave;
	close(unplug_hold);
	unplug_hold = -1;
	e->tx_len = 0; /* sent while unplugged: gone */
	record_event(e, "replug", "%s", e->pty_name);
	return "ok";
}


static const char *link_inject(struct emu *e, const char *hex)
{
	size_t len = strlen(hex);
	if (len == 0 || len % 2 || len / 2 > 240)
		return "error: usage: inject HEX (2 to 480 hex digits)";
	for (size_t i = 0; i < len; i++)
		if (hex_nibble(hex[i]) < 0)
			return "error: inject: not hex";
	size_t n = len / 2;
	if (e->tx_len + n > EMU_TX_BUFFER)
		return "error: inject: the board's queue is full";
	for (size_t i = 0; i < n; i++)
		e->tx[e->tx_len++] = (uint8_t)(hex_nibble(hex[2 * i]) << 4 | hex_nibble(hex[2 * i + 1]));
	record_event(e, "inject", "%zu", n);
	return "ok";
}

static void reply(struct emu *e, const char *fmt, const char *arg)
{
	fprintf(e->out, fmt, arg);
	fputc('\n', e->out);
	fflush(e->out);
}

static void command(struct emu *e, char *line)
{
	char *argv[4] = {0};
	int argc = 0;
	for (char *tok = strtok(line, " \t\r"); tok && argc < 4; tok = strtok(NULL, " \t\r"))
		argv[argc++] = tok;
	if (argc == 0)
		return;
	const char *cmd = argv[0];
	double a, b;
	if (!strcmp(cmd, "set")) {
		if (argc != 3) {
			reply(e, "error: usage: set INPUT 1|0|auto%s", "");
			return;
		}
		int which = -1;
		for (int i = 0; i < IN_COUNT; i++)
			if (!strcmp(argv[1], input_name(i)))
				which = i;
		if (which < 0) {
			reply(e, "error: unknown input '%s'", argv[1]);
			return;
		}
		if (!e->in_present[which]) {
			reply(e, "error: this MCU's build has no %s input", argv[1]);
			return;
		}
		if (!strcmp(argv[2], "1"))
			e->in_force[which] = FORCE_ACTIVE;
		else if (!strcmp(argv[2], "0"))
			e->in_force[which] = FORCE_INACTIVE;
		else if (!strcmp(argv[2], "auto"))
			e->in_force[which] = FORCE_AUTO;
		else {
			reply(e, "error: set: level '%s' is not 1, 0 or auto", argv[2]);
			return;
		}
		board_apply_inputs(e, 0);
		reply(e, "ok%s", "");
	} else if (!strcmp(cmd, "plate")) {
		if (argc != 2 || parse_double(argv[1], &a)) {
			reply(e, "error: usage: plate MM%s", "");
			return;
		}
		e->p.plate_mm = a;
		board_apply_inputs(e, 0);
		reply(e, "ok%s", "");
	} else if (!strcmp(cmd, "warp")) {
		if (argc != 3 || parse_double(argv[1], &a) || parse_double(argv[2], &b) || b < 0) {
			reply(e, "error: usage: warp A_MM PERIOD_S%s", "");
			return;
		}
		e->p.warp_mm = a;
		e->p.warp_period_s = b;
		board_apply_inputs(e, 0);
		reply(e, "ok%s", "");
	} else if (!strcmp(cmd, "model")) {
		if (argc != 3 || parse_double(argv[2], &a)) {
			reply(e, "error: usage: model KEY VALUE%s", "");
			return;
		}
		for (size_t i = 0; i < sizeof model_keys / sizeof model_keys[0]; i++) {
			if (!strcmp(argv[1], model_keys[i].name)) {
				*(double *)((char *)&e->p + model_keys[i].offset) = a;
				board_apply_inputs(e, 0);
				reply(e, "ok%s", "");
				return;
			}
		}
		reply(e, "error: unknown model key '%s'", argv[1]);
	} else if (!strcmp(cmd, "z")) {
		if (argc != 2 || parse_double(argv[1], &a)) {
			reply(e, "error: usage: z MM%s", "");
			return;
		}
		e->z_steps = llround(a * (double)e->pins->steps_per_mm);
		record_event(e, "z_set", "%lld", (long long)llround(board_z_mm(e) * 1000.0));
		board_apply_inputs(e, 0);
		reply(e, "ok%s", "");
	} else if (!strcmp(cmd, "status")) {
		char buf[1024];
		control_status(e, buf, sizeof buf);
		reply(e, "%s", buf);
	} else if (!strcmp(cmd, "peek")) {
		char *end1 = NULL, *end2 = NULL;
		unsigned long addr = argc == 3 ? strtoul(argv[1], &end1, 0) : 0;
		unsigned long n = argc == 3 ? strtoul(argv[2], &end2, 0) : 0;
		if (argc != 3 || !end1 || *end1 || !end2 || *end2 || n < 1 || n > 4
		    || addr + n > (unsigned long)e->avr->ramend + 1) {
			reply(e, "error: usage: peek ADDR N (N 1..4, inside data memory)%s", "");
			return;
		}
		unsigned long v = 0;
		for (unsigned long i = 0; i < n; i++)
			v |= (unsigned long)e->avr->data[addr + i] << (8 * i);
		char buf[32];
		snprintf(buf, sizeof buf, "%lu", v);
		reply(e, "peek %s", buf);
	} else if (!strcmp(cmd, "unplug") || !strcmp(cmd, "replug")) {
		if (argc != 1) {
			reply(e, "error: usage: %s", cmd);
			return;
		}
		reply(e, "%s", !strcmp(cmd, "unplug") ? link_unplug(e) : link_replug(e));
	} else if (!strcmp(cmd, "inject")) {
		reply(e, "%s", argc == 2 ? link_inject(e, argv[1]) : "error: usage: inject HEX");
	} else if (!strcmp(cmd, "drop")) {
		if (argc != 3 || parse_double(argv[1], &a) || parse_double(argv[2], &b) || a < 0 ||
		    a > 1 || b < 0) {
			reply(e, "error: usage: drop RATE SECONDS (RATE 0..1)%s", "");
			return;
		}
		record_link_drop(e, a, b);
		reply(e, "ok%s", "");
	} else if (!strcmp(cmd, "reboot")) {
		emu_reboot = 1;
		reply(e, "ok%s", "");
	} else if (!strcmp(cmd, "quit")) {
		emu_stop = 1;
		reply(e, "ok%s", "");
	} else {
		reply(e, "error: unknown command '%s'", cmd);
	}
}

void control_poll(struct emu *e)
{
	if (unplug_hold >= 0)
		e->tx_len = 0; /* unplugged: what the board sends goes nowhere */
	if (e->ctl_eof)
		return;
	struct pollfd pfd = {.fd = 0, .events = POLLIN};
	if (poll(&pfd, 1, 0) <= 0 || !(pfd.revents & (POLLIN | POLLHUP | POLLERR)))
		return;
	char buf[512];
	ssize_t n = read(0, buf, sizeof buf);
	if (n <= 0) {
		if (n == 0 || (errno != EAGAIN && errno != EINTR))
			e->ctl_eof = 1;
		return;
	}
	for (ssize_t i = 0; i < n; i++) {
		if (buf[i] == '\n') {
			e->ctl_line[e->ctl_len] = 0;
			command(e, e->ctl_line);
			e->ctl_len = 0;
		} else if (e->ctl_len + 1 < sizeof e->ctl_line) {
			e->ctl_line[e->ctl_len++] = buf[i];
		}
	}
}
