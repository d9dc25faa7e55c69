# servodyn: set-up, tests, demo and benchmark.
#
#   make test    every test: the C core (double and float), the Cortex-M4F build under QEMU,
#                the fuzz targets' builds, then the Python tests (side by side under pytest-xdist,
#                those judged against the wall clock alone after them)
#   make check   the quick loop while editing: the import layers, the C core's tests and the
#                Python tests not marked slow (no firmware under QEMU, no browser, no whole swings)
#   make demo    the main job on the simulated servo bus
#   make soak    swings with one random fault each, host and firmware (a few minutes; not in make test)
#   make fuzz    the wire codecs under libFuzzer with ASan and UBSan (FUZZ_SECONDS each, default 60)
#   make bench   timings against Pinocchio and MuJoCo, the control loop's rate, the firmware's budget,
#                contact detection scored against its goals (tools/bench/contact.py)
#   make docs    rewrite the figures the READMEs quote from the commands (tests/test_docs.py checks them)
#   make clean   remove what the build made (keeps .venv; make distclean removes it too)
#
# On a fresh Debian machine the targets install what is missing: the virtual environment in
# .venv with the project, and from Debian's packages a C compiler, the Python headers, the
# arm-none-eabi toolchain, QEMU and chromium (scripts/install/).

SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
STAMP := $(VENV)/.stamp

CORE_C := $(wildcard firmware/core/*.c)
CORE_H := $(wildcard firmware/core/*.h firmware/core/include/*.h)
HOST_C := $(wildcard host/binding/*.c host/binding/*.h hal/dynamixel/c/*.c hal/dynamixel/c/*.h)

.DEFAULT_GOAL := test
.PHONY: test check demo docs bench soak venv toolchain browser mocap-clips test-c test-mcu test-python \
        lint-imports clean distclean

test: venv toolchain browser mocap-clips
	@$(MAKE) --no-print-directory test-c test-mcu test-fuzz test-python

check: venv mocap-clips
	@$(MAKE) --no-print-directory lint-imports test-c $(FW_NATIVE)
	@echo "== Python tests not marked slow, $(TEST_JOBS) at a time"
	@$(PYTEST) -n $(TEST_JOBS) --dist loadfile -m "not slow and not serial" tests
	@echo "== Python tests judged against the wall clock, alone"
	@$(PYTEST) -m "serial and not slow" tests

demo: venv
	@echo "== servodyn demo"
	@$(VENV)/bin/servodyn swing
	@echo "servodyn is $(VENV)/bin/servodyn: run it as that, or after 'source $(VENV)/bin/activate' as servodyn (servodyn --help lists the verbs)"

# the READMEs' cog blocks run the commands whose figures they quote (scripts/docs/figures.py)
docs: venv
	@echo "== documents: the figures quoted from the commands"
	@$(VENV)/bin/python scripts/docs/docs.py

bench: venv
	@echo "== servodyn benchmark"
	@$(VENV)/bin/python -m pip install --quiet --disable-pip-version-check "mujoco>=3.2" "cmeel-eigen>=3.4"
	@$(VENV)/bin/python -m servodyn.tools.bench.core
	@$(VENV)/bin/python -m servodyn.tools.bench.contact
	@$(MAKE) --no-print-directory fw
	@$(VENV)/bin/python -m servodyn.tools.bench.loop
	@$(VENV)/bin/python -m servodyn.tools.bench.view
	@$(VENV)/bin/python -m servodyn.tools.bench.ik
	@$(VENV)/bin/python -m servodyn.tools.bench.validate
	@$(VENV)/bin/python -m servodyn.tools.bench.lerobot
	@$(VENV)/bin/python -m servodyn.tools.bench.size
	@$(VENV)/bin/python -m servodyn.tools.bench.identify
	@$(VENV)/bin/python -m servodyn.tools.bench.can
	@$(VENV)/bin/python -m servodyn.tools.bench.bringup
	@$(MAKE) --no-print-directory mocap-clips
	@$(VENV)/bin/python -m servodyn.tools.bench.mocap
	@$(MAKE) --no-print-directory fw
	@$(VENV)/bin/python -m servodyn.tools.bench.fw_budget
	@$(VENV)/bin/python -m servodyn.tools.bench.controllers

soak: venv fw
	@echo "== fault-injection soak"
	@$(VENV)/bin/servodyn soak $(SOAK_ARGS)

#---------------------------------- set-up -------------------------------------------------------

venv: $(STAMP)

# reinstall (and so rebuild the C extension) when the packaging or any C source changes
$(STAMP): pyproject.toml $(wildcard setup.py) $(CORE_C) $(CORE_H) $(HOST_C)
	@echo "== Python environment: installing servodyn into $(VENV)"
	@PYTHON=$(PYTHON) scripts/install/install-host-deps.sh
	@if [ ! -x $(VENV)/bin/python ]; then \
	  $(PYTHON) -m venv $(VENV) >/dev/null 2>&1 || { rm -rf $(VENV); \
	    scripts/install/apt-install.sh python3-venv && $(PYTHON) -m venv $(VENV); }; \
	fi
	@echo "   pip install -e '.[test]' (log: $(VENV)/pip-install.log)"
	@$(VENV)/bin/python -m pip install --disable-pip-version-check -e '.[test]' \
	    >$(VENV)/pip-install.log 2>&1 || { tail -n 30 $(VENV)/pip-install.log; \
	    echo "venv: pip install failed, full log in $(VENV)/pip-install.log"; exit 1; }
	@touch $@

toolchain:
	@scripts/install/install-toolchain.sh

# Debian's chromium for the browser tests of servodyn view
browser:
	@scripts/install/install-browser.sh

# Debian's assimp-testmodels: the public BVH clips the motion-capture tests retarget
mocap-clips:
	@scripts/install/install-mocap-clips.sh

#---------------------------------- tests --------------------------------------------------------

include tests/c/rules.mk
include firmware/mcu/rules.mk
include firmware/app/rules.mk
include fuzz/rules.mk
include firmware/posix/rules.mk
include firmware/boards/stm32f405/rules.mk
include firmware/link/rules.mk

# the cross build needs the toolchain first; toolchain is quick when it is installed
$(MCU_OBJ): | toolchain

# pytest-xdist workers for the tests that may run side by side: more than the two cores of the
# machine make test is sized for, since most tests wait (on a simulated bus, a subprocess,
# QEMU) more than they compute. --dist loadfile keeps a file's tests on one worker, so a
# module's fixture (a swing, a build) runs once.
TEST_JOBS ?= 4
PYTEST := $(VENV)/bin/python -m pytest -q -p no:cacheprovider

lint-imports: venv
	@echo "== import layers (import-linter contracts in pyproject.toml)"
	@set -o pipefail; scripts/lint-imports.sh $(VENV) | sed -n '/^Contracts/,$$p'

test-python: venv fw lint-imports
	@echo "== Python tests, $(TEST_JOBS) at a time"
	@$(PYTEST) -n $(TEST_JOBS) --dist loadfile -m "not serial" tests
	@echo "== Python tests judged against the wall clock, alone"
	@$(PYTEST) -m serial tests

#---------------------------------- clean --------------------------------------------------------

clean:
	rm -rf build out dist *.egg-info .pytest_cache $(STAMP)
	find . -path ./$(VENV) -prune -o \( -name __pycache__ -o -name '*.so' \) -print0 | \
	  xargs -0 rm -rf

distclean: clean
	rm -rf $(VENV)
