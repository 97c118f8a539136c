/*
 * posix-sim: the board's core on Linux or macOS, driving a simulated
 * two-mass gantry in real time, serving hilident on a pseudo-terminal or a
 * TCP port on 127.0.0.1.
 *
 *     posix-sim --pty                 prints the slave path (/dev/pts/N)
 *     posix-sim --tcp 0               prints socket://127.0.0.1:PORT
 *     posix-sim --print-mode          prints the plant's mode frequency, Hz, and exits
 *     posix-sim --print-plant         prints the plant's parameters, one "name value" a line
 *
 * The first line on stdout is what a host opens ([device] port).
 */
#define _POSIX_C_SOURCE 200809L

#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "board.h"
#include "hal.h"
#include "sim.h"

static struct board board; /* about 100 kB: static, not on the stack */
static volatile sig_atomic_t stop_requested;

static void on_signal(int signo)
{
	(void)signo;
	stop_requested = 1;
}

struct options {
	int pty;
	long tcp_port; /* -1: no TCP */
	unsigned baud;
	double time_scale;
	unsigned long long seed;
	int print_mode;
	int print_plant;
	int quiet;
};

static void usage(FILE *to)
{
	fputs("usage: posix-sim (--pty | --tcp PORT) [--baud N] [--time-scale X] [--seed N] [--quiet]\n"
	      "       posix-sim --print-mode | --print-plant\n"
	      "  --pty            serve a pseudo-terminal; its path is the first line on stdout\n"
	      "  --tcp PORT       serve a raw TCP line on 127.0.0.1 (0: any free port); prints socket://...\n"
	      "  --baud N         pace the board's output like a UART at N baud (default 3000000; 0: unpaced)\n"
	      "  --time-scale X   simulated seconds per wall second (default 1: real time)\n"
	      "  --seed N         seed of the sensor noise (default 1)\n"
	      "  --print-mode     print the gantry's mode frequency (Hz) and exit\n"
	      "  --print-plant    print the gantry's parameters (mode, damping, masses, friction) and exit\n"
	      "  --quiet          no messages on stderr\n",
	      to);
}

static int parse(int argc, char **argv, struct options *o)
{
	*o = (struct options){0, -1, 3000000u, 1.0, 1ull, 0, 0, 0};
	for (int i = 1; i < argc; i++) {
		const char *a = argv[i];
		const char *value = i + 1 < argc ? argv[i + 1] : NULL;
		if (!strcmp(a, "--pty")) {
			o->pty = 1;
		} else if (!strcmp(a, "--print-mode")) {
			o->print_mode = 1;
		} else if (!strcmp(a, "--print-plant")) {
			o->print_plant = 1;
		} else if (!strcmp(a, "--quiet")) {
			o->quiet = 1;
		} else if (!strcmp(a, "--help") || !strcmp(a, "-h")) {
			usage(stdout);
			exit(0);
		} else if (value && !strcmp(a, "--tcp")) {
			o->tcp_port = strtol(value, NULL, 10);
			i++;
		} else if (value && !strcmp(a, "--baud")) {
			o->baud = (unsigned)strtoul(value, NULL, 10);
			i++;
		} else if (value && !strcmp(a, "--time-scale")) {
			o->time_scale = strtod(value, NULL);
			i++;
		} else if (value && !strcmp(a, "--seed")) {
			o->seed = strtoull(value, NULL, 10);
			i++;
		} else {
			fprintf(stderr, "posix-sim: unknown or incomplete option %s\n", a);
			return -1;
		}
	}
	if (o->print_mode || o->print_plant)
		return 0;
	if (o->pty == (o->tcp_port >= 0) || o->tcp_port > 65535) {
		fputs("posix-sim: give exactly one of --pty and --tcp PORT (0-65535)\n", stderr);
		return -1;
	}
	if (!(o->time_scale > 0.0 && o->time_scale <= 64.0)) {
		fputs("posix-sim: --time-scale must be in (0, 64]\n", stderr);
		return -1;
	}
	return 0;
}

/* The simulated bench: the gantry at rest, the sensors of a typical axis. */
static void sim_init(const struct options *o)
{
	gantry_init(&sim.gantry, &gantry_default);
	sim.tick_s = 1.0 / BOARD_LOOP_RATE_HZ;
	sim.enabled = false;
	sim.torque_nm = 0.0;
	sim.encoder_m = 1e-6;
	sim.torque_noise_nm = 0.01;
	sim.laser_range_m = 0.005;
	sim.laser_m = 1e-5;
	sim.rng = o->seed ? o->seed : 1ull;
	/* wake at most every 250 us: faster simulations run ticks in batches */
	ticker_init(&sim.ticker, BOARD_LOOP_RATE_HZ * o->time_scale, 250000);
}

/* The simulated amplifier's saturation, N*m. The loop's gains power up as
 * board_config.h's [loop] defaults, which suit this gantry (about 48 kg,
 * c = 10); a host tunes them with WRITE_LOOP. */
#define SIM_TORQUE_MAX_NM 20.0

/* What a test compares hilident's findings with: the analytic mode of the
 * frictionless plant, and the friction the plant has. */
static void print_plant(int all)
{
	const struct gantry_params *p = &gantry_default;
	if (!all) {
		printf("%.9g\n", gantry_mode_hz(p));
		return;
	}
	printf("mode_hz %.9g\ndamping_ratio %.9g\n", gantry_mode_hz(p), gantry_mode_damping(p));
	printf("m1_kg %.9g\nm2_kg %.9g\nk_n_per_m %.9g\nd_ns_per_m %.9g\nc_n_per_nm %.9g\n", p->m1, p->m2, p->k,
	       p->d, p->c);
	printf("fc_nm %.9g\nfv_nm_per_mps %.9g\n", p->fc, p->fv);
}

static void report(const struct options *o)
{
	if (o->quiet)
		return;
	fprintf(stderr,
		"posix-sim: %llu loop ticks, %llu late (skipped, never burst); %llu bytes out, %lu frames in, "
		"%lu corrupt; %lu answers without room",
		(unsigned long long)board.tick, (unsigned long long)sim.ticker.late_ticks,
		(unsigned long long)sim.line.bytes_out, (unsigned long)board.rx.frames,
		(unsigned long)board.rx.corrupt, (unsigned long)board.tx.overflows);
	if (sim.line.kind == LINE_TCP)
		fprintf(stderr, "; %lu host connections", (unsigned long)sim.line.connections);
	fputc('\n', stderr);
}

int main(int argc, char **argv)
{
	struct options o;
	if (parse(argc, argv, &o) < 0) {
		usage(stderr);
		return 2;
	}
	if (o.print_mode || o.print_plant) {
		print_plant(o.print_plant);
		return 0;
	}
	int opened = o.pty ? line_open_pty(&sim.line) : line_open_tcp(&sim.line, "127.0.0.1", (unsigned)o.tcp_port);
	if (opened < 0)
		return 1;
	sim_init(&o);
	line_pace(&sim.line, o.baud, hal_time_us());
	board_init(&board, SIM_TORQUE_MAX_NM);

	struct sigaction sa;
	memset(&sa, 0, sizeof sa);
	sa.sa_handler = on_signal;
	sigaction(SIGINT, &sa, NULL);
	sigaction(SIGTERM, &sa, NULL);
	sigaction(SIGHUP, &sa, NULL);
	signal(SIGPIPE, SIG_IGN);

	printf("%s\n", sim.line.path);
	fflush(stdout);
	if (!o.quiet)
		fprintf(stderr, "posix-sim: %s on %s, gantry mode %.4f Hz, time scale %g\n", BOARD_NAME,
			sim.line.path, gantry_mode_hz(&gantry_default), o.time_scale);

	while (!stop_requested) {
		hal_wait_tick();
		board_tick(&board);
	}
	drive_disable(&board.drive); /* the line goes away: the axis stops */
	line_close(&sim.line);
	report(&o);
	return 0;
}
