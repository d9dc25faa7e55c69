# fuzz/rules.mk: libFuzzer targets with AddressSanitizer and UndefinedBehaviorSanitizer for the
# wire codecs (included by the top Makefile).
#
#   make fuzz        each target for FUZZ_SECONDS (default 60) on its seed corpus; prints the
#                    executions and crashes of each
#   make test-fuzz   a smoke of each (FUZZ_SMOKE_SECONDS, default 3), part of make test
#
# clang and libFuzzer's runtime (Debian's clang and libclang-rt-14-dev) are installed when missing
# (scripts/install/install-fuzz.sh).

FUZZ_SECONDS ?= 60
FUZZ_SMOKE_SECONDS ?= 3
FUZZ_CFLAGS := -g -O1 -std=c11 -Wall -Wextra -Werror -fsanitize=fuzzer,address,undefined \
  -fno-sanitize-recover=undefined

# one target per file in fuzz/dynamixel: build/fuzz/dxl_NAME
FUZZ_DXL := $(patsubst fuzz/dynamixel/%.c,build/fuzz/dxl_%,$(wildcard fuzz/dynamixel/*.c))
# the CAN codec, once per precision: build/fuzz/can_codec (double), build/fuzz/can32_codec (float,
# -DSD_SINGLE as the firmware builds it); both start from fuzz/can/corpus/codec
FUZZ_CAN := build/fuzz/can_codec build/fuzz/can32_codec
# the host link, once per precision: build/fuzz/link_stream (double), build/fuzz/link32_stream
# (float); both start from fuzz/link/corpus/stream
FUZZ_LINK := build/fuzz/link_stream build/fuzz/link32_stream
FUZZ_TARGETS := $(FUZZ_DXL) $(FUZZ_CAN) $(FUZZ_LINK)

build/fuzz/.cc:
	@mkdir -p $(@D)
	@scripts/install/install-fuzz.sh >$@.tmp && mv $@.tmp $@

build/fuzz/dxl_%: fuzz/dynamixel/%.c fuzz/dynamixel/fuzz.h fuzz/check.h hal/dynamixel/c/dxl.c \
                  hal/dynamixel/c/dxl.h | build/fuzz/.cc
	@echo "   clang -fsanitize=fuzzer,address,undefined $@"
	@$$(cat build/fuzz/.cc) $(FUZZ_CFLAGS) -Ihal/dynamixel/c -o $@ $< hal/dynamixel/c/dxl.c

FUZZ_CAN_DEPS := fuzz/can/codec.c fuzz/check.h hal/can/c/canmotor.c hal/can/c/canmotor.h | build/fuzz/.cc

build/fuzz/can_codec: $(FUZZ_CAN_DEPS)
	@echo "   clang -fsanitize=fuzzer,address,undefined $@"
	@$$(cat build/fuzz/.cc) $(FUZZ_CFLAGS) -Ihal/can/c -o $@ fuzz/can/codec.c hal/can/c/canmotor.c

build/fuzz/can32_codec: $(FUZZ_CAN_DEPS)
	@echo "   clang -fsanitize=fuzzer,address,undefined -DSD_SINGLE $@"
	@$$(cat build/fuzz/.cc) $(FUZZ_CFLAGS) -DSD_SINGLE -Wdouble-promotion -Wfloat-conversion -Ihal/can/c -o $@ \
	  fuzz/can/codec.c hal/can/c/canmotor.c

FUZZ_LINK_SRC := fuzz/link/stream.c firmware/link/link.c hal/dynamixel/c/dxl.c $(CORE_C)
FUZZ_LINK_DEPS := $(FUZZ_LINK_SRC) fuzz/check.h firmware/link/link.h hal/dynamixel/c/dxl.h hal/can/c/canmotor.h $(CORE_H) | build/fuzz/.cc
FUZZ_LINK_CFLAGS := $(FUZZ_CFLAGS) -ffp-contract=off -Ifirmware/link -Ifirmware/core/include -Ihal/dynamixel/c -Ihal/can/c

build/fuzz/link_stream: $(FUZZ_LINK_DEPS)
	@echo "   clang -fsanitize=fuzzer,address,undefined $@"
	@$$(cat build/fuzz/.cc) $(FUZZ_LINK_CFLAGS) -o $@ $(FUZZ_LINK_SRC) -lm

build/fuzz/link32_stream: $(FUZZ_LINK_DEPS)
	@echo "   clang -fsanitize=fuzzer,address,undefined -DSD_SINGLE $@"
	@$$(cat build/fuzz/.cc) $(FUZZ_LINK_CFLAGS) -DSD_SINGLE -Wdouble-promotion -Wfloat-conversion -o $@ \
	  $(FUZZ_LINK_SRC) -lm

.PHONY: fuzz test-fuzz
fuzz: $(FUZZ_TARGETS)
	@echo "== libFuzzer + ASan + UBSan, $(FUZZ_SECONDS) s per target"
	@fuzz/run.sh $(FUZZ_SECONDS) $(FUZZ_TARGETS)

test-fuzz: $(FUZZ_TARGETS)
	@echo "== fuzz smoke, $(FUZZ_SMOKE_SECONDS) s per target"
	@fuzz/run.sh $(FUZZ_SMOKE_SECONDS) $(FUZZ_TARGETS)
