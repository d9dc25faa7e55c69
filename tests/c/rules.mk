# tests/c/rules.mk: the C unit tests of the core, built twice (included by the top Makefile).
#
#   build/c-double/test_core   sd_real = double, as in the host and the simulation
#   build/c-float/test_core    sd_real = float, as on the microcontroller (-DSD_SINGLE)
#
# with the tests of the firmware's Dynamixel codec (hal/dynamixel/c, test_dxl.c) and of the host
# link (firmware/link, test_link.c) and of the general application's CAN bus (firmware/app/fw_can.c
# with the MIT codec, test_fw_can.c) in both.

CC ?= cc
CTEST_CFLAGS := -std=c11 -O2 -Wall -Wextra -Werror -ffp-contract=off -Ifirmware/core/include \
  -Itests/c -Ihal/dynamixel/c -Ihal/can/c -Ifirmware/link -Ifirmware/app -Ifirmware/mcu
CTEST_FLOAT_CFLAGS := -DSD_SINGLE -Wdouble-promotion -Wfloat-conversion
CTEST_SRC := $(wildcard tests/c/*.c) $(CORE_C) hal/dynamixel/c/dxl.c firmware/link/link.c firmware/app/fw_can.c \
  hal/can/c/canmotor.c
CTEST_DEPS := $(CTEST_SRC) $(wildcard tests/c/*.h) $(CORE_H) hal/dynamixel/c/dxl.h hal/can/c/canmotor.h firmware/link/link.h \
  firmware/app/fw_can.h firmware/app/fw_app.h

build/c-double/test_core: $(CTEST_DEPS)
	@mkdir -p $(@D)
	@echo "   cc $@"
	@$(CC) $(CTEST_CFLAGS) -o $@ $(CTEST_SRC) -lm

build/c-float/test_core: $(CTEST_DEPS)
	@mkdir -p $(@D)
	@echo "   cc $@ (-DSD_SINGLE)"
	@$(CC) $(CTEST_CFLAGS) $(CTEST_FLOAT_CFLAGS) -o $@ $(CTEST_SRC) -lm

.PHONY: test-c
test-c: build/c-double/test_core build/c-float/test_core
	@echo "== C unit tests, sd_real = double"
	@build/c-double/test_core
	@echo "== C unit tests, sd_real = float"
	@build/c-float/test_core
