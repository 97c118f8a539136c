/* The linux target's line and clock, shared by main.c and hal_linux.c. */
#ifndef LINUX_BOARD_H
#define LINUX_BOARD_H

#include "hw_table.h"
#include "line.h"
#include "ticker.h"

struct linux_io {
	struct line line;
	struct ticker ticker;
};

extern struct linux_io io;

#endif
