/*
 * hilident-board: the board's core as a process on an embedded Linux board
 * (a myRIO under NI Linux Real-Time, a Raspberry Pi-class board), its axis
 * behind the table of hw_user.c, serving a host on a serial device or a TCP
 * port.
 *
 *     hilident-board --tty /dev/ttyS1 --baud 921600
 *     hilident-board --tcp 5000 --bind 172.22.11.2   (a myRIO's USB network link)
 *
 * The first line on stdout is what a host opens ([device] port).
 */
#define _GNU_SOURCE /* sched_setscheduler, mlockall */

#include <sched.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>

#include "board.h"
#include "hal.h"
#include "linux_board.h"

static struct board board;
static volatile sig_atomic_t stop_requested;

static void on_signal(int signo)
{
	(void)signo;
	stop_requested = 1;
}

struct options {
	const char *tty;
	unsigned baud;
	long tcp_port; /* -1: no TCP */
	const char *bind;
	int realtime;
};

static void usage(FILE *to)
{
	fputs("usage: hilident-board (--tty DEVICE [--baud N] | --tcp PORT [--bind ADDRESS]) [--realtime]\n"
	      "  --tty DEVICE    serve the host on a serial device, 8N1 raw (default 3000000 baud)\n"
	      "  --tcp PORT      serve a raw TCP line (pyserial socket://ADDRESS:PORT)\n"
	      "  --bind ADDRESS  the TCP line's address (default 127.0.0.1; a myRIO's USB link: 172.22.11.2)\n"
	      "  --realtime      run the loop at SCHED_FIFO priority 80 with memory locked (needs root)\n",
	      to);
}

static int parse(int argc, char **argv, struct options *o)
{
	*o = (struct options){NULL, 3000000u, -1, "127.0.0.1", 0};
	for (int i = 1; i < argc; i++) {
		const char *a = argv[i];
		const char *value = i + 1 < argc ? argv[i + 1] : NULL;
		if (!strcmp(a, "--realtime")) {
			o->realtime = 1;
		} else if (!strcmp(a, "--help") || !strcmp(a, "-h")) {
			usage(stdout);
			exit(0);
		} else if (value && !strcmp(a, "--tty")) {
			o->tty = argv[++i];
		} else if (value && !strcmp(a, "--baud")) {
			o->baud = (unsigned)strtoul(argv[++i], NULL, 10);
		} else if (value && !strcmp(a, "--tcp")) {
			o->tcp_port = strtol(argv[++i], NULL, 10);
		} else if (value && !strcmp(a, "--bind")) {
			o->bind = argv[++i];
		} else {
			fprintf(stderr, "hilident-board: unknown or incomplete option %s\n", a);
			return -1;
		}
	}
	if ((o->tty != NULL) == (o->tcp_port >= 0) || o->tcp_port > 65535) {
		fputs("hilident-board: give exactly one of --tty DEVICE and --tcp PORT (0-65535)\n", stderr);
		return -1;
	}
	return 0;
}

/* Every entry the core needs is filled; else name the empty ones. */
static int table_filled(void)
{
	const struct {
		const char *name;
		int filled;
	} entries[] = {
		{"name", board_hw.name != NULL},
		{"open", board_hw.open != NULL},
		{"close", board_hw.close != NULL},
		{"read_position_m", board_hw.read_position_m != NULL},
		{"write_torque_nm", board_hw.write_torque_nm != NULL},
		{"read_torque_nm", board_hw.read_torque_nm != NULL},
		{"set_enable", board_hw.set_enable != NULL},
		{"amplifier_fault", board_hw.amplifier_fault != NULL},
	};
	int missing = 0;
	for (size_t i = 0; i < sizeof entries / sizeof entries[0]; i++) {
		if (!entries[i].filled) {
			fprintf(stderr, "%s%s", missing ? ", " : "", entries[i].name);
			missing++;
		}
	}
	if (missing)
		fputs(": empty in targets/linux/hw_user.c. Fill the hardware table for your axis (README.md, "
		      "\"The linux target\") and build again; the board does not run without it.\n",
		      stderr);
	return missing == 0;
}

static void go_realtime(void)
{
	struct sched_param sp = {.sched_priority = 80};
	if (mlockall(MCL_CURRENT | MCL_FUTURE) < 0 || sched_setscheduler(0, SCHED_FIFO, &sp) < 0)
		perror("hilident-board: --realtime");
}

int main(int argc, char **argv)
{
	struct options o;
	if (parse(argc, argv, &o) < 0) {
		usage(stderr);
		return 2;
	}
	if (!table_filled())
		return 2;
	int opened = o.tty ? line_open_tty(&io.line, o.tty, o.baud)
			   : line_open_tcp(&io.line, o.bind, (unsigned)o.tcp_port);
	if (opened < 0)
		return 1;
	if (board_hw.open() != 0) {
		fprintf(stderr, "hilident-board: %s: the hardware did not open\n", board_hw.name);
		return 1;
	}
	if (o.realtime)
		go_realtime();
	ticker_init(&io.ticker, BOARD_LOOP_RATE_HZ, 0);
	board_init(&board, board_hw.torque_max_nm);

	struct sigaction sa;
	memset(&sa, 0, sizeof sa);
	sa.sa_handler = on_signal;
	sigaction(SIGINT, &sa, NULL);
	sigaction(SIGTERM, &sa, NULL);
	sigaction(SIGHUP, &sa, NULL);
	signal(SIGPIPE, SIG_IGN);

	printf("%s\n", io.line.path);
	fflush(stdout);
	fprintf(stderr, "hilident-board: %s on %s (%s)\n", BOARD_NAME, io.line.path, board_hw.name);
	while (!stop_requested) {
		hal_wait_tick();
		board_tick(&board);
	}
	drive_disable(&board.drive);
	board_hw.close();
	line_close(&io.line);
	fprintf(stderr, "hilident-board: %llu loop ticks, %llu late\n", (unsigned long long)board.tick,
		(unsigned long long)io.ticker.late_ticks);
	return 0;
}
