/*
 * The linux target's hardware: a table of functions the user fills in
 * hw_user.c for the board at hand (README.md shows the myRIO's FPGA calls
 * each entry maps to). hal_linux.c turns the core's hardware layer into
 * calls of this table; the line and the clock are the target's own.
 */
#ifndef HW_TABLE_H
#define HW_TABLE_H

#include <stdbool.h>

#include "drive.h"

struct board_hw {
	const char *name; /* e.g. "myRIO-1900, default FPGA personality, connector C" */

	/* Open the FPGA session (or the I/O drivers) and configure the pins:
	 * encoder counting in quadrature, the analog output at 0 V, the enable
	 * output off. 0 on success. */
	int (*open)(void);
	/* Torque zero, amplifier disabled, session closed. */
	void (*close)(void);

	/* The hardware layer (core/hal.h), in SI units: */
	double (*read_position_m)(void);      /* encoder counts x metres per count */
	double (*read_load_position_m)(void); /* NULL: no load sensor (NaN is reported) */
	void (*write_torque_nm)(double torque_nm); /* N*m -> volts on the amplifier's command input */
	double (*read_torque_nm)(void);       /* current monitor (volts) -> N*m */
	void (*set_enable)(bool enabled);     /* amplifier enable output */
	bool (*amplifier_fault)(void);        /* amplifier fault input */

	/* The amplifier's saturation, N*m (its peak current times the torque
	 * constant). The loop's gains power up as board_config.h's [loop]
	 * defaults; a host tunes them for the axis with WRITE_LOOP. */
	double torque_max_nm;
};

/* Defined in hw_user.c. */
extern const struct board_hw board_hw;

#endif
