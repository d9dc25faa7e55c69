# tests/c/rules.mk: the C unit tests of the core, built twice (included by the top Makefile).
#
#   build/c-double/test_core   sd_real = double, as in the host and the simulation
#   build/c-float/test_core    sd_real = float, as on the microcontroller (-DSD_SINGLE)
#
# and, with the same flags, the tests of the firmware's Dynamixel codec (hal/dynamixel/c):
#
#   build/c-double/test_dxl, build/c-float/test_dxl
#
# test_dxl.c brings its own runner (-DSDT_DXL_MAIN) while harness.c does not list its suite.

CC ?= cc
CTEST_CFLAGS := -std=c11 -O2 -Wall -Wextra -Werror -ffp-contract=off -Ifirmware/core -Itests/c
CTEST_FLOAT_CFLAGS := -DSD_SINGLE -Wdouble-promotion -Wfloat-conversion
CTEST_SRC := $(filter-out tests/c/test_dxl.c,$(wildcard tests/c/*.c)) $(CORE_C)
CTEST_DEPS := $(CTEST_SRC) $(wildcard tests/c/*.h) $(CORE_H)

DXL_C := hal/dynamixel/c/dxl.c
DXL_TEST_SRC := tests/c/test_dxl.c $(DXL_C)
DXL_TEST_DEPS := $(DXL_TEST_SRC) hal/dynamixel/c/dxl.h tests/c/harness.h
DXL_TEST_CFLAGS := -DSDT_DXL_MAIN -Ihal/dynamixel/c

build/c-double/test_core: $(CTEST_DEPS)
	@mkdir -p $(@D)
	@echo "   cc $@"
	@$(CC) $(CTEST_CFLAGS) -o $@ $(CTEST_SRC) -lm

build/c-float/test_core: $(CTEST_DEPS)
	@mkdir -p $(@D)
	@echo "   cc $@ (-DSD_SINGLE)"
	@$(CC) $(CTEST_CFLAGS) $(CTEST_FLOAT_CFLAGS) -o $@ $(CTEST_SRC) -lm

build/c-double/test_dxl: $(DXL_TEST_DEPS)
	@mkdir -p $(@D)
	@echo "   cc $@"
	@$(CC) $(CTEST_CFLAGS) $(DXL_TEST_CFLAGS) -o $@ $(DXL_TEST_SRC)

build/c-float/test_dxl: $(DXL_TEST_DEPS)
	@mkdir -p $(@D)
	@echo "   cc $@ (-DSD_SINGLE)"
	@$(CC) $(CTEST_CFLAGS) $(CTEST_FLOAT_CFLAGS) $(DXL_TEST_CFLAGS) -o $@ $(DXL_TEST_SRC)

.PHONY: test-c
test-c: build/c-double/test_core build/c-float/test_core build/c-double/test_dxl build/c-float/test_dxl
	@echo "== C unit tests, sd_real = double"
	@build/c-double/test_core
	@build/c-double/test_dxl
	@echo "== C unit tests, sd_real = float"
	@build/c-float/test_core
	@build/c-float/test_dxl
