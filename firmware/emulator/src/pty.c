/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * pty.c - UART0's other end: a raw pty whose slave is symlinked at --pty.
 *
 * The host keeps a slave descriptor open itself, so a client closing and reopening the
 * port never makes the master read EIO or poll HUP.
 *
 * Auto-reset (--bootloader): on a USB Arduino, opening the port asserts DTR, which pulls
 * RESET low through a capacitor. A pty has no DTR line (its TIOCMSET fails), and with our
 * own slave descriptor open the master never sees HUP come and go; what is visible is the
 * open itself: an inotify IN_OPEN watch on the slave's device node fires for every open(2)
 * of it by any process (ours was opened before the watch), so each open of the port
 * resets the MCU, as DTR would. A DTR/RTS toggle on an open port (avrdude's -c arduino and
 * -c wiring do one right after opening) has no pty counterpart: it is not modelled, and
 * the open's reset stands in for it. The symlink is made under a temporary
 * name and renamed into place, so the path never points at a dead pty.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <libgen.h>
#include <limits.h>
#include <stdlib.h>
#include <string.h>
#include <sys/inotify.h>
#include <sys/stat.h>
#include <termios.h>
#include <unistd.h>

#include "host.h"

static int raw_mode(int fd)
{
	struct termios t;
	if (tcgetattr(fd, &t) != 0)
		return -1;
	cfmakeraw(&t);
	t.c_cc[VMIN] = 1;
	t.c_cc[VTIME] = 0;
	return tcsetattr(fd, TCSANOW, &t);
}

int pty_open(struct emu *e)
{
	char dir_buf[PATH_MAX];
	struct stat st;
	snprintf(dir_buf, sizeof dir_buf, "%s", e->pty_path);
	const char *dir = dirname(dir_buf);
	if (stat(dir, &st) != 0 || !S_ISDIR(st.st_mode)) {
		fprintf(stderr, "dthc-emulated-board-host: --pty %s: directory %s does not exist\n",
			e->pty_path, dir);
		return -1;
	}
	if (lstat(e->pty_path, &st) == 0 && !S_ISLNK(st.st_mode)) {
		fprintf(stderr,
			"dthc-emulated-board-host: --pty %s exists and is not a symlink: refusing to "
			"replace it\n",
			e->pty_path);
		return -1;
	}
	e->master_fd = posix_openpt(O_RDWR | O_NOCTTY);
	if (e->master_fd < 0 || grantpt(e->master_fd) != 0 || unlockpt(e->master_fd) != 0 ||
	    ptsname_r(e->master_fd, e->pty_name, sizeof e->pty_name) != 0) {
		fprintf(stderr, "dthc-emulated-board-host: cannot create a pty: %s\n",
			strerror(errno));
		return -1;
	}
	e->slave_fd = open(e->pty_name, O_RDWR | O_NOCTTY);
	if (e->slave_fd < 0 || raw_mode(e->slave_fd) != 0) {
		fprintf(stderr, "dthc-emulated-board-host: cannot open %s: %s\n", e->pty_name,
			strerror(errno));
		return -1;
	}
	raw_mode(e->master_fd);
	if (e->bootloader_path) {
		e->open_watch_fd = inotify_init1(IN_NONBLOCK | IN_CLOEXEC);
		if (e->open_watch_fd < 0 ||
		    inotify_add_watch(e->open_watch_fd, e->pty_name, IN_OPEN) < 0) {
			fprintf(stderr, "dthc-emulated-board-host: cannot watch %s for opens: %s\n",
				e->pty_name, strerror(errno));
			return -1;
		}
	}
	fcntl(e->master_fd, F_SETFL, fcntl(e->master_fd, F_GETFL) | O_NONBLOCK);
	fcntl(e->master_fd, F_SETFD, FD_CLOEXEC);
	fcntl(e->slave_fd, F_SETFD, FD_CLOEXEC);

	char tmp[PATH_MAX];
	char base_buf[PATH_MAX];
	snprintf(dir_buf, sizeof dir_buf, "%s", e->pty_path);
	snprintf(base_buf, sizeof base_buf, "%s", e->pty_path);
	snprintf(tmp, sizeof tmp, "%s/.%s.%d", dirname(dir_buf), basename(base_buf), (int)getpid());
	unlink(tmp);
	if (symlink(e->pty_name, tmp) != 0 || rename(tmp, e->pty_path) != 0) {
		fprintf(stderr, "dthc-emulated-board-host: cannot link %s to %s: %s\n",
			e->pty_path, e->pty_name, strerror(errno));
		unlink(tmp);
		return -1;
	}
	return 0;
}

void pty_close(struct emu *e)
{
	char target[PATH_MAX];
	ssize_t n = readlink(e->pty_path, target, sizeof target - 1);
	if (n > 0) {
		target[n] = 0;
		if (!strcmp(target, e->pty_name)) /* only our own link: a newer run may own it */
			unlink(e->pty_path);
	}
	if (e->open_watch_fd >= 0)
		close(e->open_watch_fd);
	e->open_watch_fd = -1;
	if (e->master_fd >= 0)
		close(e->master_fd);
	if (e->slave_fd >= 0)
		close(e->slave_fd);
	e->master_fd = e->slave_fd = -1;
}

/* Write what the board sent; what the pty cannot take now stays queued (up to the buffer;
 * beyond it bytes are dropped and counted, as a real USB bridge's buffer overflows). */
void pty_flush_tx(struct emu *e)
{
	if (!e->tx_len)
		return;
	ssize_t n = write(e->master_fd, e->tx, e->tx_len);
	if (n <= 0)
		return;
	e->tx_len -= (size_t)n;
	if (e->tx_len)
		memmove(e->tx, e->tx + n, e->tx_len);
}

/* How many times a client opened the port since the last call (0 without --bootloader). */
int pty_opened(struct emu *e)
{
	if (e->open_watch_fd < 0)
		return 0;
	int opens = 0;
	for (;;) {
		char buf[4096] __attribute__((aligned(__alignof__(struct inotify_event))));
		ssize_t n = read(e->open_watch_fd, buf, sizeof buf);
		if (n <= 0)
			return opens;
		for (char *p = buf; p < buf + n;) {
			const struct inotify_event *ev = (const struct inotify_event *)p;
			if (ev->mask & IN_OPEN)
				opens++;
			p += sizeof *ev + ev->len;
		}
	}
}
