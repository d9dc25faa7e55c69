# firmware/boards/stm32f405/rules.mk: the servodyn firmware on the STM32F405 (included by the top
# Makefile after firmware/app/rules.mk): the same application, core, codec and generated tables as
# the MPS2 images (FW_SRC without the MPS2 board files), on this board layer, Cortex-M4F at 168 MHz.
#   build/fw/f405/servodyn-fw.elf   run by QEMU -M netduinoplus2 (host/hil.py, board f405)
# A BOARD_HIL build like the others (FW_HIL=0 for a board: the console on USART2, no semihosting).

F405_DIR := firmware/boards/stm32f405
F405_ELF := $(FW_DIR)/f405/servodyn-fw.elf
F405_SRC := $(filter-out firmware/mcu/%,$(FW_SRC)) $(wildcard $(F405_DIR)/*.c)
F405_OBJ := $(patsubst %.c,$(FW_DIR)/f405/%.o,$(F405_SRC))
F405_CFLAGS := $(FW_ARCH_an386) $(FW_CFLAGS) -DBOARD_CPU_HZ=168000000u -I$(F405_DIR)

$(FW_DIR)/f405/%.o: %.c $(FW_DEPS) $(wildcard $(F405_DIR)/*.h) firmware/mcu/board_uart_ring.h firmware/mcu/board_systick.h $(F405_DIR)/rules.mk
	@mkdir -p $(@D)
	@$(MCU_CC) $(F405_CFLAGS) -c -o $@ $<

$(F405_ELF): $(F405_OBJ) $(F405_DIR)/stm32f405.ld
	@echo "   arm-none-eabi-gcc $@ (STM32F405, float, -O2)"
	@$(MCU_CC) $(FW_ARCH_an386) -nostartfiles --specs=nosys.specs -Wl,--gc-sections \
	  -Wl,--defsym=STACK_SIZE=$(FW_STACK) -Wl,-T,$(F405_DIR)/stm32f405.ld \
	  -Wl,-Map,$(FW_DIR)/f405/servodyn-fw.map -o $@ $(F405_OBJ) -lm

$(F405_OBJ): | toolchain

fw: $(F405_ELF)
