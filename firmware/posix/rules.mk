# firmware/posix/rules.mk: the firmware as a Linux process, the native loop (included by the top
# Makefile after firmware/app/rules.mk). The same application, core, codec and generated tables as
# the Cortex-M builds, single precision, on firmware/posix/board_posix.c: a termios serial port
# for the UART, clock_nanosleep for SysTick, nanosecond clock counts.
#   build/fw/native/servodyn-fw PORT [realtime] [log=FILE] ...

FW_NATIVE := $(FW_DIR)/native/servodyn-fw
FW_NATIVE_CFLAGS := -std=c11 -O2 -Wall -Wextra -Werror -Wdouble-promotion -Wfloat-conversion \
  -ffp-contract=fast -fno-math-errno -DSD_SINGLE -DBOARD_CPU_HZ=1000000000u -DFW_TOLERATE_OVERRUN=1 \
  -include $(FW_GEN)/servodyn_gen.h -Ifirmware/core/include -Ifirmware/mcu -Ifirmware/app \
  -Ihal/dynamixel/c -Ihal/can/c -Ifirmware/posix -I$(FW_GEN)
FW_NATIVE_SRC := $(CORE_C) firmware/posix/board_posix.c firmware/posix/board_slcan.c firmware/app/fw_step.c firmware/app/fw_bus.c hal/dynamixel/c/dxl.c \
  $(FW_GEN)/servodyn_gen.c

# fw_main.c's main() becomes fw_app_main(): the board's main() opens the port first
$(FW_NATIVE): $(FW_NATIVE_SRC) firmware/app/fw_main.c $(FW_DEPS) firmware/posix/board_posix.h firmware/posix/rules.mk
	@echo "   cc $@ (Linux, float, -O2)"
	@mkdir -p $(@D)
	@$(CC) $(FW_NATIVE_CFLAGS) -Dmain=fw_app_main -c -o $(@D)/fw_main.o firmware/app/fw_main.c
	@$(CC) $(FW_NATIVE_CFLAGS) -o $@ $(FW_NATIVE_SRC) $(@D)/fw_main.o -lm

fw: $(FW_NATIVE)

# The general application (fw_link.c): no generated robot, the host loads one over the host link
# (link=PATH) up to the compiled sizes below; the same step, bus code, core and codec, and the CAN
# bus (fw_can.c, the MIT codec) through an SLCAN adapter (can=PATH, board_slcan.c).
#   build/fw/native/servodyn-fw-link [PORT] link=PATH [can=PATH] [realtime] [ticks=N] [baud=N]
FW_LINK_NATIVE := $(FW_DIR)/native/servodyn-fw-link
FW_LINK_SIZES := -DSD_MAX_BODY=16 -DSD_MAX_DOF=16 -DSD_MAX_KNOT=64
FW_LINK_NATIVE_CFLAGS := -std=c11 -O2 -Wall -Wextra -Werror -Wdouble-promotion -Wfloat-conversion \
  -ffp-contract=fast -fno-math-errno -DSD_SINGLE $(FW_LINK_SIZES) -DBOARD_CPU_HZ=1000000000u \
  -DFW_TOLERATE_OVERRUN=1 -Ifirmware/core/include -Ifirmware/mcu -Ifirmware/app -Ifirmware/link \
  -Ihal/dynamixel/c -Ihal/can/c -Ifirmware/posix -I$(FW_GEN)
FW_LINK_NATIVE_SRC := $(CORE_C) firmware/posix/board_posix.c firmware/posix/board_slcan.c firmware/app/fw_step.c \
  firmware/app/fw_bus.c firmware/app/fw_can.c firmware/link/link.c hal/dynamixel/c/dxl.c hal/can/c/canmotor.c

$(FW_LINK_NATIVE): $(FW_LINK_NATIVE_SRC) firmware/app/fw_link.c $(CORE_H) firmware/app/fw_app.h firmware/mcu/board.h \
                   firmware/app/fw_can.h firmware/posix/board_posix.h hal/can/c/canmotor.h \
                   firmware/link/link.h hal/dynamixel/c/dxl.h $(FW_GEN)/fw_dynamixel.h firmware/posix/rules.mk
	@echo "   cc $@ (Linux, float, -O2, the host link's application)"
	@mkdir -p $(@D)
	@$(CC) $(FW_LINK_NATIVE_CFLAGS) -Dmain=fw_app_main -c -o $(@D)/fw_link.o firmware/app/fw_link.c
	@$(CC) $(FW_LINK_NATIVE_CFLAGS) -o $@ $(FW_LINK_NATIVE_SRC) $(@D)/fw_link.o -lm

fw: $(FW_LINK_NATIVE)
