/* The hardware layer of posix-sim: the core's ten functions on a simulated axis. */
#include <math.h>

#include "hal.h"
#include "sim.h"

struct sim sim;

/* Standard normal numbers: xorshift64* and Box-Muller (seeded: runs repeat). */
static double uniform(void)
{
	sim.rng ^= sim.rng >> 12;
	sim.rng ^= sim.rng << 25;
	sim.rng ^= sim.rng >> 27;
	return ((sim.rng * 0x2545F4914F6CDD1DULL) >> 11) * (1.0 / 9007199254740992.0);
}

static double gaussian(void)
{
	const double pi = 3.14159265358979323846;
	double u = uniform();
	return sqrt(-2.0 * log(u > 0.0 ? u : 1e-300)) * cos(2.0 * pi * uniform());
}

uint64_t hal_time_us(void)
{
	return monotonic_us();
}

void hal_wait_tick(void)
{
	/* the physics of the tick just computed, with the torque it wrote */
	gantry_step(&sim.gantry, sim.torque_nm, sim.tick_s);
	ticker_wait(&sim.ticker);
}

double hal_read_position_m(void)
{
	return floor(sim.gantry.p1 / sim.encoder_m) * sim.encoder_m;
}

double hal_read_load_position_m(void)
{
	if (fabs(sim.gantry.p2 - sim.gantry.p1) > sim.laser_range_m)
		return NAN;
	return floor(sim.gantry.p2 / sim.laser_m + 0.5) * sim.laser_m;
}

void hal_write_torque_nm(double torque_nm)
{
	sim.torque_nm = sim.enabled ? torque_nm : 0.0;
}

double hal_read_torque_nm(void)
{
	return sim.torque_nm + sim.torque_noise_nm * gaussian();
}

void hal_set_enable(bool enabled)
{
	sim.enabled = enabled;
	if (!enabled)
		sim.torque_nm = 0.0;
}

bool hal_amplifier_fault(void)
{
	return false;
}

size_t hal_serial_read(uint8_t *buf, size_t max)
{
	return line_read(&sim.line, buf, max);
}

size_t hal_serial_write(const uint8_t *buf, size_t n)
{
	return line_write(&sim.line, buf, n, monotonic_us());
}
