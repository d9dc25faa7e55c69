# firmware/link/rules.mk: the host link (firmware/link/link.c) cross-compiled for the Cortex-M4F with
# the firmware's flags (float, -Werror), as part of make test-mcu: it must call no heap and no
# double-precision helper (scripts/check-mcu.sh's rule for the image); its code size and worst stack
# frame are printed. Its unit tests run in test-c (tests/c/test_link.c, both precisions), its
# fuzz target in test-fuzz (fuzz/link/stream.c, both precisions).

LINK_MCU_OBJ := $(MCU_DIR)/link/link.o

$(LINK_MCU_OBJ): firmware/link/link.c firmware/link/link.h hal/dynamixel/c/dxl.h hal/can/c/canmotor.h $(CORE_H) firmware/link/rules.mk \
                 | toolchain
	@mkdir -p $(@D)
	@$(MCU_CC) $(MCU_CFLAGS) -Ifirmware/link -Ihal/dynamixel/c -Ihal/can/c -c -o $@ $<

.PHONY: test-mcu-link
test-mcu-link: $(LINK_MCU_OBJ)
	@if $(MCU_CC:gcc=nm) $< | grep -E ' U (_?(malloc|calloc|realloc|free|sbrk)(_r)?|__aeabi_d[a-z0-9]*|__aeabi_f2d|sin|cos|sqrt|fabs|exp|tanh)$$'; then \
	  echo "check-mcu: FAIL: the host link calls the heap or double precision ($<)"; exit 1; fi
	@echo "== host link, Cortex-M4F (-DSD_SINGLE): $$(arm-none-eabi-size $< | awk 'NR==2 {print $$1 " bytes of code, " $$3 " of RAM"}'), worst stack frame $$(sort -t$$'\t' -k2 -n $(MCU_DIR)/link/link.su | tail -n 1 | cut -f2) bytes"

test-mcu: test-mcu-link
