/*
 * Codes and sizes of the hilident serial board protocol, version 1
 * (drivers/myrio-board/PROTOCOL.md; section numbers below refer to it).
 */
#ifndef PROTOCOL_H
#define PROTOCOL_H

#define PROTOCOL_VERSION 1
#define HEADER_BYTES 4           /* version u8, type u8, seq u16 (section 3) */
#define CRC_BYTES 4              /* section 2 */
#define MAX_FRAME_BYTES 65536u   /* stuffed frame without its delimiter (section 2) */
#define MAX_BLOCK_SAMPLES 4096u  /* CONFIGURE block_samples (section 4.2) */
#define SAMPLES_HEAD_BYTES 24    /* SAMPLES body before its rows (section 4.12) */
#define STATUS_BODY_BYTES 31     /* section 4.13 */
#define FILTER_BODY_BYTES 22     /* section 4.7 */
#define WRITE_LOOP_BODY_BYTES 16 /* section 4.16: the four gains */
#define MAX_TEXT_BYTES 255       /* str: len u8 + UTF-8 (section 3) */

/* Section 4: message types. Host to board below 0x80. */
enum msg_type {
	MSG_IDENTIFY = 0x01,
	MSG_CONFIGURE = 0x02,
	MSG_SET_LIMITS = 0x03,
	MSG_START = 0x04,
	MSG_STOP = 0x05,
	MSG_EXCITATION = 0x06,
	MSG_STATUS_REQUEST = 0x07,
	MSG_WRITE_FILTER = 0x08,
	MSG_READ_FILTER = 0x09,
	MSG_CLEAR_FAULT = 0x0A,
	MSG_PING = 0x0B,
	MSG_READ_LOOP = 0x0C,
	MSG_WRITE_LOOP = 0x0D,
	MSG_IDENTITY = 0x81,
	MSG_ACK = 0x82,
	MSG_NAK = 0x83,
	MSG_SAMPLES = 0x84,
	MSG_STATUS = 0x85,
	MSG_FILTER = 0x86,
	MSG_EVENT = 0x87,
	MSG_LOOP = 0x88,
};

/* Section 11.1: NAK error codes. */
enum error_code {
	ERR_BAD_VERSION = 1,
	ERR_UNKNOWN_TYPE = 2,
	ERR_BAD_LENGTH = 3,
	ERR_BAD_STATE = 4,
	ERR_BAD_ARGUMENT = 5,
	ERR_BUFFER_OVERFLOW = 6,
	ERR_FAULT_ACTIVE = 7,
};

/* Section 11.2: EVENT codes. */
enum event_code {
	EVT_LIMIT_TRIP = 1,
	EVT_UNDERRUN = 2,
	EVT_FAULT = 3, /* reserved: a version-1 board does not send it */
	EVT_FINISHED = 4,
	EVT_STOPPED = 5,
	EVT_WATCHDOG = 6,
};

/* Section 11.3: states. */
enum board_state {
	ST_IDLE = 0,
	ST_CONFIGURED = 1,
	ST_RUNNING = 2,
	ST_FAULT = 3,
};

/* Section 11.4: what the excitation drives. */
enum run_mode {
	MODE_TORQUE = 0,
	MODE_TORQUE_INJECTION = 1,
	MODE_VELOCITY = 2,
	MODE_POSITION = 3,
	N_MODES
};

/* Section 11.5: on-wire value formats. */
enum value_format {
	FMT_F32 = 0,
	FMT_I16 = 1,
	FMT_I32 = 2,
	N_FORMATS
};

/* Section 11.6: STATUS.fault. */
enum fault_code {
	FAULT_NONE = 0,
	FAULT_TORQUE_LIMIT = 1,
	FAULT_VELOCITY_LIMIT = 2,
	FAULT_POSITION_LIMIT = 3,
	FAULT_WATCHDOG = 4,
};

/* Section 7: SAMPLES flags. */
#define FLAG_CLIPPED 0x0001u
#define FLAG_UNDERRUN 0x0002u
#define FLAG_FAULT 0x0004u
#define FLAG_LAST 0x0008u

/* Bytes of one value in `format` (section 11.5); 0 for an unknown format. */
static inline unsigned format_bytes(unsigned format)
{
	return format == FMT_I16 ? 2u : (format == FMT_F32 || format == FMT_I32) ? 4u : 0u;
}

#endif
