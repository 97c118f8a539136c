#define _DEFAULT_SOURCE /* posix_openpt, ptsname, the Linux baud rates above 230 400 */
#define _XOPEN_SOURCE 700

#include "line.h"

#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <termios.h>
#include <unistd.h>

#ifndef MSG_NOSIGNAL
#define MSG_NOSIGNAL 0 /* macOS: SIGPIPE is ignored by the targets instead */
#endif

static void line_reset(struct line *l, enum line_kind kind)
{
	memset(l, 0, sizeof *l);
	l->kind = kind;
	l->fd = l->listen_fd = l->slave_fd = -1;
}

static int nonblocking(int fd)
{
	int flags = fcntl(fd, F_GETFL);
	return flags < 0 ? -1 : fcntl(fd, F_SETFL, flags | O_NONBLOCK);
}

/* A raw 8-bit line: no echo, no line discipline, 8N1, no flow control. */
static int make_raw(int fd, speed_t speed)
{
	struct termios t;
	if (tcgetattr(fd, &t) < 0)
		return -1;
	t.c_iflag &= ~(tcflag_t)(IGNBRK | BRKINT | PARMRK | ISTRIP | INLCR | IGNCR | ICRNL | IXON | IXOFF | IXANY);
	t.c_oflag &= ~(tcflag_t)OPOST;
	t.c_lflag &= ~(tcflag_t)(ECHO | ECHONL | ICANON | ISIG | IEXTEN);
	t.c_cflag &= ~(tcflag_t)(CSIZE | PARENB | CSTOPB | CRTSCTS);
	t.c_cflag |= CS8 | CREAD | CLOCAL;
	t.c_cc[VMIN] = 0;
	t.c_cc[VTIME] = 0;
	if (speed && (cfsetispeed(&t, speed) < 0 || cfsetospeed(&t, speed) < 0))
		return -1;
	return tcsetattr(fd, TCSANOW, &t);
}

int line_open_pty(struct line *l)
{
	line_reset(l, LINE_PTY);
	l->fd = posix_openpt(O_RDWR | O_NOCTTY);
	if (l->fd < 0 || grantpt(l->fd) < 0 || unlockpt(l->fd) < 0 || nonblocking(l->fd) < 0) {
		perror("pseudo-terminal");
		return -1;
	}
	const char *name = ptsname(l->fd);
	if (!name) {
		perror("ptsname");
		return -1;
	}
	snprintf(l->path, sizeof l->path, "%s", name);
	l->slave_fd = open(l->path, O_RDWR | O_NOCTTY);
	if (l->slave_fd < 0 || make_raw(l->slave_fd, 0) < 0) {
		perror(l->path);
		return -1;
	}
	return 0;
}

static speed_t speed_of(unsigned baud)
{
	static const struct {
		unsigned baud;
		speed_t speed;
	} speeds[] = {
		{9600, B9600}, {19200, B19200}, {38400, B38400}, {57600, B57600}, {115200, B115200},
		{230400, B230400},
#ifdef B460800
		{460800, B460800},
#endif
#ifdef B921600
		{921600, B921600},
#endif
#ifdef B1000000
		{1000000, B1000000},
#endif
#ifdef B2000000
		{2000000, B2000000},
#endif
#ifdef B3000000
		{3000000, B3000000},
#endif
#ifdef B4000000
		{4000000, B4000000},
#endif
	};
	for (size_t i = 0; i < sizeof speeds / sizeof speeds[0]; i++)
		if (speeds[i].baud == baud)
			return speeds[i].speed;
	return 0;
}

int line_open_tty(struct line *l, const char *device, unsigned baud)
{
	line_reset(l, LINE_TTY);
	speed_t speed = speed_of(baud);
	if (!speed) {
		fprintf(stderr, "%s: baud rate %u is not one this system's termios knows\n", device, baud);
		return -1;
	}
	l->fd = open(device, O_RDWR | O_NOCTTY | O_NONBLOCK);
	if (l->fd < 0 || make_raw(l->fd, speed) < 0) {
		perror(device);
		return -1;
	}
	tcflush(l->fd, TCIOFLUSH);
	snprintf(l->path, sizeof l->path, "%s", device);
	return 0;
}

int line_open_tcp(struct line *l, const char *address, unsigned port)
{
	line_reset(l, LINE_TCP);
	struct sockaddr_in sa;
	memset(&sa, 0, sizeof sa);
	sa.sin_family = AF_INET;
	sa.sin_port = htons((uint16_t)port);
	if (inet_pton(AF_INET, address, &sa.sin_addr) != 1) {
		fprintf(stderr, "%s: not an IPv4 address\n", address);
		return -1;
	}
	int one = 1;
	l->listen_fd = socket(AF_INET, SOCK_STREAM, 0);
	if (l->listen_fd < 0 || setsockopt(l->listen_fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one) < 0 ||
	    bind(l->listen_fd, (struct sockaddr *)&sa, sizeof sa) < 0 || listen(l->listen_fd, 4) < 0 ||
	    nonblocking(l->listen_fd) < 0) {
		perror("tcp");
		return -1;
	}
	socklen_t len = sizeof sa;
	getsockname(l->listen_fd, (struct sockaddr *)&sa, &len);
	snprintf(l->path, sizeof l->path, "socket://%s:%u", address, (unsigned)ntohs(sa.sin_port));
	return 0;
}

void line_pace(struct line *l, unsigned baud, uint64_t now_us)
{
	l->bytes_per_us = baud / 10.0 / 1e6;
	/* a UART's FIFO plus what one late wake-up of the loop lets pile up */
	l->burst = l->bytes_per_us * 2000.0 > 64.0 ? l->bytes_per_us * 2000.0 : 64.0;
	l->credit = 0.0;
	l->paced_at_us = now_us;
}

static void drop_connection(struct line *l)
{
	if (l->fd >= 0)
		close(l->fd);
	l->fd = -1;
}

/* A host connecting replaces the previous one. */
static void accept_pending(struct line *l)
{
	int conn = accept(l->listen_fd, NULL, NULL);
	if (conn < 0)
		return;
	int one = 1;
	setsockopt(conn, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
	nonblocking(conn);
	drop_connection(l);
	l->fd = conn;
	l->connections++;
}

size_t line_read(struct line *l, uint8_t *buf, size_t max)
{
	if (l->kind == LINE_TCP)
		accept_pending(l);
	if (l->fd < 0)
		return 0;
	ssize_t n = read(l->fd, buf, max);
	if (n > 0)
		return (size_t)n;
	if (l->kind == LINE_TCP && (n == 0 || (errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR)))
		drop_connection(l); /* the host hung up or died: the line is free for the next one */
	return 0;
}

size_t line_write(struct line *l, const uint8_t *buf, size_t n, uint64_t now_us)
{
	if (l->bytes_per_us > 0.0) {
		l->credit += (double)(now_us - l->paced_at_us) * l->bytes_per_us;
		l->paced_at_us = now_us;
		if (l->credit > l->burst)
			l->credit = l->burst; /* an idle line saves up no bandwidth */
		if ((double)n > l->credit)
			n = (size_t)l->credit;
		if (n == 0)
			return 0;
	}
	size_t taken = n;
	if (l->fd >= 0) {
		ssize_t w = l->kind == LINE_TCP ? send(l->fd, buf, n, MSG_NOSIGNAL) : write(l->fd, buf, n);
		if (w >= 0)
			taken = (size_t)w;
		else if (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR)
			taken = 0;
		else if (l->kind == LINE_TCP)
			drop_connection(l); /* what the host did not take is lost, as on a real line */
	}
	l->credit -= (double)taken;
	l->bytes_out += taken;
	return taken;
}

void line_close(struct line *l)
{
	drop_connection(l);
	if (l->listen_fd >= 0)
		close(l->listen_fd);
	if (l->slave_fd >= 0)
		close(l->slave_fd);
	l->listen_fd = l->slave_fd = -1;
}
