/* The hardware layer of the linux target: the user's table (hw_user.c) for the
 * axis, the target's own line (tty or TCP) and clock. */
#include <math.h>

#include "hal.h"
#include "linux_board.h"

struct linux_io io;

uint64_t hal_time_us(void)
{
	return monotonic_us();
}

void hal_wait_tick(void)
{
	ticker_wait(&io.ticker);
}

double hal_read_position_m(void)
{
	return board_hw.read_position_m();
}

double hal_read_load_position_m(void)
{
	return board_hw.read_load_position_m ? board_hw.read_load_position_m() : NAN;
}

void hal_write_torque_nm(double torque_nm)
{
	board_hw.write_torque_nm(torque_nm);
}

double hal_read_torque_nm(void)
{
	return board_hw.read_torque_nm();
}

void hal_set_enable(bool enabled)
{
	board_hw.set_enable(enabled);
}

bool hal_amplifier_fault(void)
{
	return board_hw.amplifier_fault();
}

size_t hal_serial_read(uint8_t *buf, size_t max)
{
	return line_read(&io.line, buf, max);
}

size_t hal_serial_write(const uint8_t *buf, size_t n)
{
	return line_write(&io.line, buf, n, monotonic_us());
}
