# firmware/mcu/rules.mk: the core cross-compiled for a Cortex-M4F (included by the top Makefile),
# with the CAN motor frame codec (hal/can/c) in float beside it (canmotor_check.c runs it).
#
# One object per source so -fstack-usage writes one .su per file; scripts/check-mcu.sh then
# checks the linked ELF (no heap, no double precision), reports size and stack, and runs it
# under QEMU (mps2-an386).

MCU_CC := arm-none-eabi-gcc
MCU_DIR := build/mcu
MCU_ELF := $(MCU_DIR)/servodyn-mcu.elf
MCU_ARCH := -mcpu=cortex-m4 -mfpu=fpv4-sp-d16 -mfloat-abi=hard -mthumb
MCU_CFLAGS := $(MCU_ARCH) -std=c11 -O2 -Wall -Wextra -Werror -Wdouble-promotion \
  -Wfloat-conversion -ffp-contract=fast -fno-math-errno -ffunction-sections -fdata-sections -fstack-usage \
  -DSD_SINGLE -DSD_MAX_BODY=16 -DSD_MAX_DOF=24 -DSD_MAX_KNOT=32 -Ifirmware/core/include -Ifirmware/mcu -Ihal/can/c
MCU_LDFLAGS := $(MCU_ARCH) -nostartfiles --specs=nosys.specs -Wl,--gc-sections \
  -Wl,-T,firmware/mcu/mps2.ld -Wl,-Map,$(MCU_DIR)/servodyn-mcu.map
MCU_SRC := $(CORE_C) $(filter-out firmware/mcu/board_link.c,$(wildcard firmware/mcu/*.c)) hal/can/c/canmotor.c
MCU_OBJ := $(patsubst %.c,$(MCU_DIR)/%.o,$(MCU_SRC))

$(MCU_DIR)/%.o: %.c $(CORE_H) $(wildcard firmware/mcu/*.h) hal/can/c/canmotor.h firmware/mcu/rules.mk
	@mkdir -p $(@D)
	@$(MCU_CC) $(MCU_CFLAGS) -c -o $@ $<

$(MCU_ELF): $(MCU_OBJ) firmware/mcu/mps2.ld
	@echo "   arm-none-eabi-gcc $@ (-DSD_SINGLE, Cortex-M4F, -O2)"
	@$(MCU_CC) $(MCU_LDFLAGS) -o $@ $(MCU_OBJ) -lm

.PHONY: test-mcu
test-mcu: $(MCU_ELF)
	@echo "== Cortex-M4F build of the core: link check and QEMU run (mps2-an386)"
	@scripts/check-mcu.sh $(MCU_ELF) $(MCU_DIR)
