/*
 * The board's serial line on a POSIX system: a pseudo-terminal, a serial
 * device (tty), or a raw TCP port (what pyserial opens as socket://HOST:PORT;
 * a serial-to-Ethernet converter, or a myRIO's USB network link).
 *
 * Reads and writes never block. One host at a time on TCP: a new connection
 * replaces the old one, and bytes written while nobody is connected are
 * lost, as on a cable nobody listens to.
 */
#ifndef LINE_H
#define LINE_H

#include <stddef.h>
#include <stdint.h>

enum line_kind { LINE_PTY, LINE_TTY, LINE_TCP };

struct line {
	enum line_kind kind;
	int fd;        /* pty master, tty, or the connected TCP socket; -1: none */
	int listen_fd; /* TCP listening socket */
	int slave_fd;  /* pty slave, held open so the master never reads EIO */
	char path[160]; /* what a host opens: /dev/pts/N, the tty, socket://127.0.0.1:PORT */
	/* pacing of what is written, like a UART at `baud` (0: unpaced) */
	double bytes_per_us;
	double credit;
	double burst;
	uint64_t paced_at_us;
	uint64_t bytes_out;
	unsigned connections;
};

/* Each returns 0, or -1 with a message on stderr. */
int line_open_pty(struct line *l);
int line_open_tty(struct line *l, const char *device, unsigned baud);
int line_open_tcp(struct line *l, const char *address, unsigned port);

/* Write no faster than a UART at `baud` (8N1: 10 bits a byte); 0: as fast as
 * the other end reads. */
void line_pace(struct line *l, unsigned baud, uint64_t now_us);

size_t line_read(struct line *l, uint8_t *buf, size_t max);
size_t line_write(struct line *l, const uint8_t *buf, size_t n, uint64_t now_us);
void line_close(struct line *l);

#endif
