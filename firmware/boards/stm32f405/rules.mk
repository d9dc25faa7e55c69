# firmware/boards/stm32f405/rules.mk: the servodyn firmware on the STM32F405 (included by the top
# Makefile after firmware/app/rules.mk): the same application, core, codec and generated tables as
# the MPS2 images (FW_SRC without the MPS2 board files), on this board layer, Cortex-M4F at 168 MHz.
#   build/fw/f405/servodyn-fw.elf            run by QEMU -M netduinoplus2 (host/hil.py, board f405)
#   build/fw/f405-link/servodyn-fw-link.elf  the general application (fw_link.c, the host link on
#                                            USART3: -serial #2; hil.run_qemu_link(board="f405"))
# A BOARD_HIL build like the others (FW_HIL=0 for a board: the console on USART2, no semihosting).

F405_DIR := firmware/boards/stm32f405
F405_ELF := $(FW_DIR)/f405/servodyn-fw.elf
F405_BOARD_C := $(filter-out $(F405_DIR)/board_link.c,$(wildcard $(F405_DIR)/*.c))
F405_SRC := $(filter-out firmware/mcu/%,$(FW_SRC)) $(F405_BOARD_C)
F405_OBJ := $(patsubst %.c,$(FW_DIR)/f405/%.o,$(F405_SRC))
F405_CFLAGS := $(FW_ARCH_an386) $(FW_CFLAGS) -DBOARD_CPU_HZ=168000000u -I$(F405_DIR)

F405_DEPS := $(wildcard $(F405_DIR)/*.h) firmware/mcu/board_uart_ring.h firmware/mcu/board_systick.h \
  firmware/mcu/board_link_ring.h $(F405_DIR)/rules.mk

$(FW_DIR)/f405/%.o: %.c $(FW_DEPS) $(F405_DEPS)
	@mkdir -p $(@D)
	@$(MCU_CC) $(F405_CFLAGS) -c -o $@ $<

$(F405_ELF): $(F405_OBJ) $(F405_DIR)/stm32f405.ld
	@echo "   arm-none-eabi-gcc $@ (STM32F405, float, -O2)"
	@$(MCU_CC) $(FW_ARCH_an386) -nostartfiles --specs=nosys.specs -Wl,--gc-sections \
	  -Wl,--defsym=STACK_SIZE=$(FW_STACK) -Wl,-T,$(F405_DIR)/stm32f405.ld \
	  -Wl,-Map,$(FW_DIR)/f405/servodyn-fw.map -o $@ $(F405_OBJ) -lm

$(F405_OBJ): | toolchain

fw: $(F405_ELF)

# The general application (firmware/app/rules.mk's FW_LINK_SRC, sized for a microcontroller) on this
# board layer with its host link (board_link.c)
F405_LINK_ELF := $(FW_DIR)/f405-link/servodyn-fw-link.elf
F405_LINK_SRC := $(filter-out firmware/mcu/%,$(FW_LINK_SRC)) $(F405_BOARD_C) $(F405_DIR)/board_link.c
F405_LINK_OBJ := $(patsubst %.c,$(FW_DIR)/f405-link/%.o,$(F405_LINK_SRC))
F405_LINK_CFLAGS := $(FW_ARCH_an386) $(filter-out -DFW_LINK_BOARD=%,$(FW_LINK_CFLAGS)) -DFW_LINK_BOARD='"stm32f405"' \
  -DBOARD_CPU_HZ=168000000u -I$(F405_DIR)

$(FW_DIR)/f405-link/%.o: %.c $(FW_LINK_DEPS) $(F405_DEPS) | toolchain
	@mkdir -p $(@D)
	@$(MCU_CC) $(F405_LINK_CFLAGS) -c -o $@ $<

$(F405_LINK_ELF): $(F405_LINK_OBJ) $(F405_DIR)/stm32f405.ld
	@echo "   arm-none-eabi-gcc $@ (STM32F405, float, -O2, the host link's application)"
	@$(MCU_CC) $(FW_ARCH_an386) -nostartfiles --specs=nosys.specs -Wl,--gc-sections \
	  -Wl,--defsym=STACK_SIZE=$(FW_STACK) -Wl,-T,$(F405_DIR)/stm32f405.ld \
	  -Wl,-Map,$(FW_DIR)/f405-link/servodyn-fw-link.map -o $@ $(F405_LINK_OBJ) -lm

fw: $(F405_LINK_ELF)
