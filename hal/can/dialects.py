"""The dialects of MIT-style CAN motors: how each one answers, where, and what its status means.

    mit       Ben Katz's mini-cheetah motorcontrol firmware: replies [id, p, v|t] (6 bytes, 7 with
              the voltage) to id CAN_MASTER (0), one per frame received, packed before acting on it.
    damiao    Damiao DM-J series in MIT mode: 8-byte feedback on the Master ID (CAN_ID + 0x10 by
              the vendor's advice) with a status nibble and the MOS and coil temperatures;
              registers read and written through id 0x7FF.
    cubemars  CubeMars AK series, MIT firmware: 8-byte reply [id, p, v|i, temperature, error] to id 0.
"""

from __future__ import annotations

import math

from dataclasses import dataclass
from typing import Callable

from . import frames

# Damiao's status nibble (feedback byte 0, high nibble)
DAMIAO_DISABLED, DAMIAO_ENABLED = 0x0, 0x1
DAMIAO_STATUS = {
    0x0: "disabled", 0x1: "enabled", 0x8: "overvoltage", 0x9: "undervoltage", 0xA: "overcurrent",
    0xB: "MOS over-temperature", 0xC: "coil over-temperature", 0xD: "communication lost",
    0xE: "overload",
}
# CubeMars' error byte
CUBEMARS_ERRORS = {
    0: "none", 1: "over-temperature", 2: "over-current", 3: "over-voltage", 4: "under-voltage",
    5: "encoder fault", 6: "phase current unbalance",
}

# Damiao registers (number, name, float32?): DM_CAN.py's DM_variable, openarm_can's RID (dm_motor_constants.hpp)
REG_OT, REG_MST_ID, REG_ESC_ID, REG_TIMEOUT, REG_CTRL_MODE = 2, 7, 8, 9, 10
REG_GR = 20               # Gr, the gear ratio, read-only: names the model (10 a J4310, 40 a J4340)
REG_PMAX, REG_VMAX, REG_TMAX = 21, 22, 23
UINT_REGISTERS = frozenset({7, 8, 9, 10, 13, 14, 15, 16, 35, 36})
CTRL_MODES = {1: "MIT", 2: "position-velocity", 3: "velocity", 4: "force-position"}
MIT_MODE = 1
TIMEOUT_UNIT = 50e-6      # s per TIMEOUT register unit
# A Damiao motor as it leaves the factory answers commands on CAN ID 1 and sends every frame on
# Master ID 0: damiao-motor (its README and every CLI command address a motor as motor_id 0x01,
# feedback_id 0x00), openarm_can's discovery listens on id + 0x10 and on 0x00, DM_CAN.py routes a
# register reply on id 0 by the CAN ID in its bytes ("in case someone set MasterID to 0"). The
# vendor's advice is Master ID = CAN ID + 0x10, never 0 (Seeed's Damiao wiki).
FACTORY_CAN_ID, FACTORY_MASTER_ID = 1, 0
# Register writes (0x55) change RAM only; 0xAA stores them all to flash, which the vendor's tools
# do only after a disable frame (DM_CAN.save_motor_param: "before save disable the motor";
# openarm_can change_motor_id_commands.cpp: "Disable motor (Required before saving to Flash)"),
# with a warning of about 10,000 write cycles (openarm_can).
FLASH_CYCLES = 10_000


def register_bits(rid: int, value: float) -> int:
    """A register value as its frame's 4 bytes (uint32 registers as integers, the rest float32)."""
    return int(value) if rid in UINT_REGISTERS else frames.float_bits(float(value))


def range_matches(value: float, expected: float) -> bool:
    """Whether a PMAX/VMAX/TMAX register holds the configuration's range (float32 rounding aside)."""
    return abs(value - expected) <= 1e-4 * max(1.0, abs(value))


RANGE_REGISTERS = {REG_PMAX: "p_max", REG_VMAX: "v_max", REG_TMAX: "t_max"}   # register -> frames.Ranges field


def register_value(rid: int, g: frames.Register) -> float:
    """A register frame's value, by its number's type."""
    return g.value if rid in UINT_REGISTERS else g.as_float


@dataclass(frozen=True)
class Dialect:
    name: str
    feedback_id: Callable[[int], int]           # default reply id of a motor with this command id
    reply_length: tuple[int, ...]
    unpack: Callable[[frames.Ranges, bytes], frames.Reply]
    pack: Callable[[frames.Ranges, frames.Reply], bytes]
    reply_key: Callable[[bytes], int]            # the id a reply names (routing on a shared feedback id)
    faults: Callable[[frames.Reply, bool], tuple[str, ...]]   # (reply, torque on) -> fault names
    registers: bool = False                     # Damiao's 0x7FF register frames
    # °C of the winding a reply reports (Damiao: the coil's; CubeMars: the motor's), nan without one
    winding_temperature: Callable[[frames.Reply], float] = lambda reply: math.nan


def _damiao_faults(reply: frames.Reply, torque_on: bool) -> tuple[str, ...]:
    if reply.status == DAMIAO_ENABLED or (reply.status == DAMIAO_DISABLED and not torque_on):
        return ()
    if reply.status == DAMIAO_DISABLED:
        return ("disabled while torque is on",)
    return (DAMIAO_STATUS.get(reply.status, f"unknown status 0x{reply.status:X}"),)


def _cubemars_faults(reply: frames.Reply, torque_on: bool) -> tuple[str, ...]:
    return () if reply.status == 0 else (CUBEMARS_ERRORS.get(reply.status, f"unknown error {reply.status}"),)


DIALECTS = {
    "mit": Dialect("mit", lambda can_id: 0, (6, 7), frames.unpack_mit_reply, frames.pack_mit_reply,
                   lambda data: data[0], lambda reply, on: ()),
    "damiao": Dialect("damiao", lambda can_id: can_id + 0x10, (8,), frames.unpack_damiao_feedback,
                      frames.pack_damiao_feedback, lambda data: data[0] & 0xF, _damiao_faults, registers=True,
                      winding_temperature=lambda reply: float(reply.temperature2)),
    "cubemars": Dialect("cubemars", lambda can_id: 0, (8,), frames.unpack_cubemars_reply,
                        frames.pack_cubemars_reply, lambda data: data[0], _cubemars_faults,
                        winding_temperature=lambda reply: float(reply.temperature)),
}
