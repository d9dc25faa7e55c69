"""Builds the C core into two extension modules, double (servodyn._core) and float (servodyn._core32),
and the firmware's Dynamixel codec into servodyn.hal.dynamixel._dxl (beside the backend that uses it)."""
import glob

import numpy
from setuptools import Extension, setup

CORE = sorted(glob.glob("firmware/core/*.c"))
FLAGS = ["-std=c11", "-O3", "-ffp-contract=off", "-Wall", "-Wextra"]


def core_module(name, *defines):
    return Extension(
        f"servodyn.{name}",
        sources=[*sorted(glob.glob("host/binding/*.c")), *CORE],
        include_dirs=["firmware/core/include", "host/binding", numpy.get_include()],
        define_macros=[("SD_MODULE_NAME", name), *[(d, "1") for d in defines]],
        extra_compile_args=FLAGS,
    )


DXL = Extension("servodyn.hal.dynamixel._dxl", sources=["hal/dynamixel/c/_dxl.c", "hal/dynamixel/c/dxl.c"],
                include_dirs=["hal/dynamixel/c"], extra_compile_args=FLAGS)

setup(ext_modules=[core_module("_core"), core_module("_core32", "SD_SINGLE"), DXL])
