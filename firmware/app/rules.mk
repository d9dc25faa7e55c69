# firmware/app/rules.mk: the servodyn firmware (included by the top Makefile).
#
# `servodyn codegen --config $(FW_CONFIG)` writes the robot's model, servo mapping, gains and
# swing as C (build/fw/gen); the firmware compiles them in with the core (single precision), the
# Dynamixel codec (hal/dynamixel/c) and the board code, for two boards QEMU models:
#   mps2-an386  Cortex-M4F  build/fw/an386/servodyn-fw.elf
#   mps2-an500  Cortex-M7   build/fw/an500/servodyn-fw.elf
# Both are hardware-in-the-loop builds (BOARD_HIL, board_io.c): a reply is waited for until the
# simulated bus says on its sync line (UART1) that nothing more is coming, so the emulated clock
# cannot run while the host is slow. FW_HIL=0 (after make clean) builds a board's own reply
# timeout alone.

FW_CONFIG ?= replica
FW_DIR := build/fw
FW_GEN := $(FW_DIR)/gen
FW_GEN_FILES := $(FW_GEN)/servodyn_gen.c $(FW_GEN)/servodyn_gen.h $(FW_GEN)/fw_dynamixel.h
FW_BOARDS := an386 an500
FW_ARCH_an386 := -mcpu=cortex-m4 -mfpu=fpv4-sp-d16 -mfloat-abi=hard -mthumb
FW_ARCH_an500 := -mcpu=cortex-m7 -mfpu=fpv5-d16 -mfloat-abi=hard -mthumb
FW_STACK := 4096
FW_HIL ?= 1
FW_CFLAGS := -std=c11 -O2 -Wall -Wextra -Werror -Wdouble-promotion -Wfloat-conversion \
  -ffp-contract=fast -fno-math-errno -ffunction-sections -fdata-sections -fstack-usage \
  -fcallgraph-info=su -DSD_SINGLE $(if $(filter 1,$(FW_HIL)),-DBOARD_HIL) -include $(FW_GEN)/servodyn_gen.h \
  -Ifirmware/core/include -Ifirmware/mcu -Ifirmware/app -Ihal/dynamixel/c -Ihal/can/c -I$(FW_GEN)
FW_APP_C := firmware/app/fw_main.c firmware/app/fw_step.c firmware/app/fw_bus.c    # the compiled-in robot's application
FW_SRC := $(CORE_C) firmware/mcu/startup.c firmware/mcu/board_io.c $(FW_APP_C) \
  hal/dynamixel/c/dxl.c $(FW_GEN)/servodyn_gen.c
FW_DEPS := $(CORE_H) $(wildcard firmware/mcu/*.h firmware/app/*.h hal/dynamixel/c/*.h) \
  $(FW_GEN)/servodyn_gen.h $(FW_GEN)/fw_dynamixel.h firmware/app/rules.mk
FW_ELFS := $(foreach b,$(FW_BOARDS),$(FW_DIR)/$(b)/servodyn-fw.elf)
FW_CODEGEN_DEPS := $(STAMP) $(wildcard tools/codegen.py host/control/*.py host/model/*.py \
  host/model/builtin/*.toml host/control/motions/*.toml hal/config.py hal/dynamixel/control_table.py \
  hal/dynamixel/units.py hal/configs/*.toml hal/safety.py hal/backend.py host/loop/contact.py)

# codegen writes only what changed, so the touch keeps make from asking again
$(FW_GEN_FILES) &: $(FW_CODEGEN_DEPS)
	@echo "   servodyn codegen --config $(FW_CONFIG) -o $(FW_GEN)"
	@$(VENV)/bin/servodyn codegen --config $(FW_CONFIG) -o $(FW_GEN) >/dev/null
	@touch $(FW_GEN_FILES)

define FW_BOARD_RULES
$(FW_DIR)/$(1)/%.o: %.c $(FW_DEPS)
	@mkdir -p $$(@D)
	@$(MCU_CC) $(FW_ARCH_$(1)) $(FW_CFLAGS) -c -o $$@ $$<

$(FW_DIR)/$(1)/servodyn-fw.elf: $(patsubst %.c,$(FW_DIR)/$(1)/%.o,$(FW_SRC)) firmware/mcu/mps2.ld
	@echo "   arm-none-eabi-gcc $$@ (mps2-$(1), float, -O2)"
	@$(MCU_CC) $(FW_ARCH_$(1)) -nostartfiles --specs=nosys.specs -Wl,--gc-sections \
	  -Wl,--defsym=STACK_SIZE=$(FW_STACK) -Wl,-T,firmware/mcu/mps2.ld \
	  -Wl,-Map,$(FW_DIR)/$(1)/servodyn-fw.map -o $$@ $$(filter %.o,$$^) -lm
endef
$(foreach b,$(FW_BOARDS),$(eval $(call FW_BOARD_RULES,$(b))))

$(foreach b,$(FW_BOARDS),$(patsubst %.c,$(FW_DIR)/$(b)/%.o,$(FW_SRC))): | toolchain

.PHONY: fw
fw: $(FW_ELFS)

# The general application (fw_link.c, the host link on UART2: -serial #2) for mps2-an386 (no CAN
# controller: fw_can.c's weak board_can_* say so), sized for a microcontroller: build/fw/an386-link/servodyn-fw-link.elf
FW_LINK_MCU_SIZES := -DSD_MAX_BODY=8 -DSD_MAX_DOF=8 -DSD_MAX_KNOT=32
FW_LINK_ELF := $(FW_DIR)/an386-link/servodyn-fw-link.elf
FW_LINK_CFLAGS := $(filter-out -include $(FW_GEN)/servodyn_gen.h,$(FW_CFLAGS)) $(FW_LINK_MCU_SIZES) \
  -DFW_LINK_BOARD='"mps2-an386"' -Ifirmware/link
FW_LINK_SRC := $(CORE_C) firmware/mcu/startup.c firmware/mcu/board_io.c firmware/mcu/board_link.c firmware/app/fw_link.c \
  firmware/app/fw_step.c firmware/app/fw_bus.c firmware/app/fw_can.c firmware/link/link.c hal/dynamixel/c/dxl.c \
  hal/can/c/canmotor.c
FW_LINK_DEPS := $(CORE_H) $(wildcard firmware/mcu/*.h firmware/app/*.h firmware/link/*.h hal/dynamixel/c/*.h) \
  hal/can/c/canmotor.h \
  $(FW_GEN)/fw_dynamixel.h firmware/app/rules.mk

$(FW_DIR)/an386-link/%.o: %.c $(FW_LINK_DEPS) | toolchain
	@mkdir -p $(@D)
	@$(MCU_CC) $(FW_ARCH_an386) $(FW_LINK_CFLAGS) -c -o $@ $<

$(FW_LINK_ELF): $(patsubst %.c,$(FW_DIR)/an386-link/%.o,$(FW_LINK_SRC)) firmware/mcu/mps2.ld
	@echo "   arm-none-eabi-gcc $@ (mps2-an386, float, -O2, the host link's application)"
	@$(MCU_CC) $(FW_ARCH_an386) -nostartfiles --specs=nosys.specs -Wl,--gc-sections \
	  -Wl,--defsym=STACK_SIZE=$(FW_STACK) -Wl,-T,firmware/mcu/mps2.ld \
	  -Wl,-Map,$(FW_DIR)/an386-link/servodyn-fw-link.map -o $@ $(filter %.o,$^) -lm

fw: $(FW_LINK_ELF)
