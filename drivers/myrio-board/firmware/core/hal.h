/*
 * The hardware layer: what the core needs of a board, in ten functions.
 *
 * Each target (targets/posix-sim, targets/linux, targets/cortex-m) is one
 * file that defines them. The core never touches hardware otherwise.
 *
 * Units are SI. Positions are on the encoder's axis, metres; the target
 * turns counts, volts and amperes into metres and N*m with its own scaling
 * (README.md, "Wiring").
 */
#ifndef HAL_H
#define HAL_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

/* Monotonic wall-clock time, microseconds. The watchdog measures host
 * silence with it (PROTOCOL.md section 8: wall time, whatever the loop does). */
uint64_t hal_time_us(void);

/* Block until the next loop tick (period 1 / BOARD_LOOP_RATE_HZ). Called by
 * the target's main loop before each board_tick(), not by the core. */
void hal_wait_tick(void);

/* Encoder position of the motor side, m. */
double hal_read_position_m(void);

/* Load sensor (a laser on the load), m on the encoder's axis; NaN when it is
 * out of range or not fitted. */
double hal_read_load_position_m(void);

/* Torque command to the power stage, N*m (the target scales it to its
 * analog output, e.g. +-10 V for a servo amplifier in torque mode). Held
 * until the next call. */
void hal_write_torque_nm(double torque_nm);

/* Measured torque applied over this tick, N*m (the amplifier's current
 * monitor times the torque constant). Read after hal_write_torque_nm(). */
double hal_read_torque_nm(void);

/* Amplifier enable line: true lets current flow. */
void hal_set_enable(bool enabled);

/* Amplifier fault line: true while the amplifier reports a fault. */
bool hal_amplifier_fault(void);

/* Serial line, host side. Neither call blocks. hal_serial_read() returns the
 * bytes received (0: none); hal_serial_write() returns how many of `n` bytes
 * the line took (fewer when its transmit FIFO is full). */
size_t hal_serial_read(uint8_t *buf, size_t max);
size_t hal_serial_write(const uint8_t *buf, size_t n);

#endif
