/*
 * FILL THIS IN: the linux target's hardware table (hw_table.h).
 *
 * Every entry is empty, and the board refuses to start until each one
 * (read_load_position_m excepted) is filled: a board that cannot read its
 * encoder or command its amplifier must never answer a host as if it could.
 *
 * README.md ("The linux target on a myRIO") shows which calls of NI's C
 * Support for NI myRIO each entry maps to; the sketch below is that mapping
 * as code. NOT TESTED ON HARDWARE: check every register, scale and sign on
 * your bench with the amplifier disabled before the first session.
 */
#include <stddef.h>

#include "hw_table.h"

const struct board_hw board_hw = {
	.name = NULL,
	.open = NULL,
	.close = NULL,
	.read_position_m = NULL,
	.read_load_position_m = NULL,
	.write_torque_nm = NULL,
	.read_torque_nm = NULL,
	.set_enable = NULL,
	.amplifier_fault = NULL,
	/* At most the torque of the amplifier's peak current (README.md, "Wiring"). */
	.torque_max_nm = 20.0,
};

#if 0 /* A sketch for a myRIO-1900 on MSP connector C (untested). */
#include "MyRio.h"   /* NI "C Support for NI myRIO": MyRio_Open, the register names */
#include "AIO.h"     /* Aio_Scaling, Aio_Write, Aio_Read */
#include "DIO.h"     /* Dio_WriteBit, Dio_ReadBit */
#include "Encoder.h" /* Encoder_Configure, Encoder_Counter */

#define M_PER_COUNT 1e-6   /* encoder: metres per quadrature count (pinion, lead, line count x 4) */
#define VOLTS_PER_NM 0.5   /* amplifier command input: 10 V = 20 N*m */
#define NM_PER_VOLT 2.0    /* amplifier current monitor, scaled to torque */

extern NiFpga_Session myrio_session;
static MyRio_Encoder enc;
static MyRio_Aio command, monitor;
static MyRio_Dio enable_out, fault_in;

static int myrio_open(void)
{
	if (MyRio_IsNotSuccess(MyRio_Open()))
		return -1;
	enc.cnfg = ENCC_0CNFG;
	enc.stat = ENCC_0STAT;
	enc.cntr = ENCC_0CNTR;
	uint8_t select;
	NiFpga_ReadU8(myrio_session, SYSSELECTC, &select);
	NiFpga_WriteU8(myrio_session, SYSSELECTC, select | (1 << 0)); /* C/DIO0,2 to encoder 0 */
	Encoder_Configure(&enc, Encoder_Enable | Encoder_SignalMode, Encoder_Enabled | Encoder_QuadPhase);
	command = (MyRio_Aio){.val = AOC_0VAL, .wght = AOC_0WGHT, .ofst = AOC_0OFST, .set = AOSYSGO, .is_signed = NiFpga_True};
	monitor = (MyRio_Aio){.val = AIC_0VAL, .wght = AIC_0WGHT, .ofst = AIC_0OFST, .is_signed = NiFpga_True};
	Aio_Scaling(&command);
	Aio_Scaling(&monitor);
	Aio_Write(&command, 0.0);
	enable_out = (MyRio_Dio){.dir = DIOC_70DIR, .out = DIOC_70OUT, .in = DIOC_70IN, .bit = 5};
	fault_in = (MyRio_Dio){.dir = DIOC_70DIR, .out = DIOC_70OUT, .in = DIOC_70IN, .bit = 7};
	Dio_WriteBit(&enable_out, NiFpga_False);
	return 0;
}

static void myrio_close(void)
{
	Aio_Write(&command, 0.0);
	Dio_WriteBit(&enable_out, NiFpga_False);
	MyRio_Close();
}

static double myrio_position(void)
{
	return (int32_t)Encoder_Counter(&enc) * M_PER_COUNT; /* the counter wraps as a signed 32-bit value */
}

static void myrio_torque(double nm)
{
	Aio_Write(&command, nm * VOLTS_PER_NM);
}

static double myrio_measured_torque(void)
{
	return Aio_Read(&monitor) * NM_PER_VOLT;
}

static void myrio_enable(bool on)
{
	Dio_WriteBit(&enable_out, on ? NiFpga_True : NiFpga_False);
}

static bool myrio_fault(void)
{
	return Dio_ReadBit(&fault_in) == NiFpga_False; /* fault output active low */
}

const struct board_hw board_hw = {
	.name = "myRIO-1900, default FPGA personality, connector C",
	.open = myrio_open,
	.close = myrio_close,
	.read_position_m = myrio_position,
	.read_load_position_m = NULL,
	.write_torque_nm = myrio_torque,
	.read_torque_nm = myrio_measured_torque,
	.set_enable = myrio_enable,
	.amplifier_fault = myrio_fault,
	.torque_max_nm = 20.0,
};
#endif
