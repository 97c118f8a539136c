# The Cortex-M4 skeleton (STM32F4), built by `make cortex-m` in the firmware folder.
# Needs arm-none-eabi-gcc and newlib (Debian: gcc-arm-none-eabi, libnewlib-arm-none-eabi).

BUILD ?= build/cortex-m
PREFIX ?= arm-none-eabi-
CC = $(PREFIX)gcc
SIZE = $(PREFIX)size

ARCH = -mcpu=cortex-m4 -mthumb -mfloat-abi=hard -mfpu=fpv4-sp-d16
# The receive buffer holds the largest useful EXCITATION (board_config.h): 4 + 6 + 4 x 4096 bytes.
DEFS = -DBOARD_RX_PAYLOAD_MAX=16394u
CFLAGS = $(ARCH) -std=c11 -Wall -Wextra -Werror -Os -ffunction-sections -fdata-sections $(DEFS) \
	-Icore -Itargets/cortex-m
LDFLAGS = $(ARCH) -Ttargets/cortex-m/board.ld -Wl,--gc-sections -Wl,-Map=$(BUILD)/board.map \
	--specs=nano.specs --specs=nosys.specs -nostartfiles

SRC = $(wildcard core/*.c) $(wildcard targets/cortex-m/*.c)
HEADERS = $(wildcard core/*.h) $(wildcard targets/cortex-m/*.h)

.PHONY: size

size: $(BUILD)/board.elf
	@echo "flash = text + data, RAM = data + bss (the stack takes what is left):"
	$(SIZE) $<

$(BUILD)/board.elf: $(SRC) $(HEADERS) targets/cortex-m/board.ld
	@mkdir -p $(BUILD)
	$(CC) $(CFLAGS) $(LDFLAGS) -o $@ $(SRC) -lm
