"""The bench: a simulated robot as it stands on a real bench before bring-up, for the bring-up
commands (scan, setup, doctor, calibrate, reboot, ...) to be tested without hardware.

    bench = Lab(factory=True, connected=("r_elbow_flexion",), store="bench.json")
    robot = SimulatedRobot(load_config("replica"), bench=bench)

- ``factory``: every device starts as it leaves the factory (its kind's ``factory_fresh``: a
  Dynamixel servo at ID 1, 57600 baud, ...) unless the store holds its memory; without it, a
  device the store does not hold starts as the configuration sets it up.
- ``connected``: the dofs whose device is wired to its bus (None: every dof). The others neither
  hear nor answer; the plant still holds their joints, limp (their torque stays off).
- ``store``: a JSON file (`Store`) of each device's non-volatile memory by the joint's dof (the
  physical device in that slot: whatever ID it is given, it stays there) and of each joint's
  mounting. Read at start, written at start and whenever a device's memory changes, so the bench
  carries over from one run of the simulator to the next.
- ``mounting``: how each horn is physically mounted (`Mounting`: direction and zero offset), which
  the plant uses in place of the configuration's — a plant that is not the model. Unless given here
  it is the store's, else with ``factory`` a seeded one (``seed``) that differs from the
  configuration on purpose (every zero 200 to 600 ticks of a 4096-tick turn off, one joint mounted
  against the configuration's direction) so a calibration has something to find; else the
  configuration's. The store records it: the truth a test compares a calibration with.
- ``memory``: per dof, items of the non-volatile memory set on the bench over the factory's or the
  store's (a Dynamixel servo's ``{"firmware_version": 44}``).

A device kind takes part through the `Device` protocol, called generically here: every kind that
implements it joins the bench without a change to this file.
"""

from __future__ import annotations

import json
import math
import os
import random
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

from servodyn.errors import InputError
from servodyn.hal.dynamixel.control_table import TICKS_PER_REV

FORMAT = 1                      # the store file's "format"
ZERO_OFF = (200 * 2 * math.pi / TICKS_PER_REV, 600 * 2 * math.pi / TICKS_PER_REV)   # rad: a factory zero's error
BENCH_METHODS = ("nonvolatile", "restore", "power_cycle", "factory_fresh")


class Device(Protocol):
    """What the bench asks of a device (a Dynamixel servo, a CAN motor)."""

    on_nonvolatile: Callable | None     # set by the bench: called with the device after its memory changed

    def nonvolatile(self) -> dict:
        """Its non-volatile memory, JSON-able: what a power cycle keeps."""

    def restore(self, state: dict) -> None:
        """That memory (or a part of it) put back, then powered up with it; ValueError, before any
        change, for a state it cannot hold."""

    def power_cycle(self) -> None:
        """Off and on: volatile state back to its defaults (torque off), the memory kept."""

    @classmethod
    def factory_fresh(cls, spec, **hardware) -> "Device":
        """One as it leaves the factory. `spec`: the joint's device model; `hardware`: what the
        configuration says the device is, not its memory (Dynamixel: where the horn sits)."""


def require(kind: type, what: str) -> None:
    """ValueError (one line) unless devices of `kind` ("CAN motors") take part in a bench."""
    if not all(hasattr(kind, name) for name in BENCH_METHODS):
        raise InputError(f"the bench's factory state for {what} is not available")


@dataclass(frozen=True)
class Mounting:
    """How a joint's horn is mounted: its turn is direction · gear · q + zero_offset (rad)."""
    direction: int
    zero_offset: float

    def __post_init__(self):
        if self.direction not in (1, -1) or not math.isfinite(self.zero_offset):
            raise InputError(f"a mounting's direction is +1 or -1 and its zero offset a finite angle "
                             f"(got {self.direction}, {self.zero_offset})")


@dataclass(frozen=True)
class Lab:
    """A bench's description (the module's docstring). JSON-able (to_json, from_json), so a
    simulator in another process gets the same bench."""
    factory: bool = False
    connected: Sequence[str] | None = None
    store: str | os.PathLike | None = None
    mounting: Mapping[str, Mounting] | None = None
    memory: Mapping[str, Mapping[str, int]] = field(default_factory=dict)
    seed: int = 0

    def to_json(self) -> str:
        return json.dumps({
            "factory": self.factory, "connected": None if self.connected is None else list(self.connected),
            "store": None if self.store is None else os.fspath(self.store),
            "mounting": None if self.mounting is None else {dof: [m.direction, m.zero_offset]
                                                             for dof, m in self.mounting.items()},
            "memory": {dof: dict(items) for dof, items in self.memory.items()}, "seed": self.seed})

    @classmethod
    def from_json(cls, text: str) -> "Lab":
        d = json.loads(text)
        mounting = d.get("mounting")
        return cls(factory=d["factory"], connected=d["connected"], store=d["store"],
                   mounting=None if mounting is None else {dof: Mounting(*m) for dof, m in mounting.items()},
                   memory=d["memory"], seed=d["seed"])

    def set_up(self, config, joints: Sequence) -> "BenchSetup":
        """The bench for a configuration's joints (in the model's dof order); ValueError for a dof
        the configuration does not have, or a store that is not of this robot's devices."""
        dofs = [j.dof for j in joints]
        for named, what in ((self.connected or (), "connected"), (self.mounting or {}, "mounting"),
                            (self.memory, "memory")):
            unknown = [dof for dof in named if dof not in dofs]
            if unknown:
                raise InputError(f"the bench's {what}: no dof {', '.join(map(repr, unknown))} in "
                                 f"'{config.name}' (dofs: {', '.join(dofs)})")
        store = Store(self.store) if self.store is not None else None
        mounting = {j.dof: Mounting(j.direction, j.zero_offset) for j in joints}
        if self.mounting is not None:
            mounting.update(self.mounting)
        elif store is not None and store.mounting:
            mounting.update({dof: m for dof, m in store.mounting.items() if dof in mounting})
        elif self.factory:
            mounting.update(factory_mounting(joints, self.seed))
        connected = set(dofs if self.connected is None else self.connected)
        return BenchSetup(self, store, mounting, connected)


def factory_mounting(joints: Sequence, seed: int) -> dict[str, Mounting]:
    """A mounting that differs from the configuration's, drawn from `seed`: each zero ZERO_OFF off
    either way; one joint mounted against its configured direction, its horn at the middle of the
    joint's range where the configuration expects it (plus that joint's own zero error)."""
    rng = random.Random(seed)
    turned = rng.randrange(len(joints))
    out = {}
    for k, j in enumerate(joints):
        error = rng.uniform(*ZERO_OFF) * rng.choice((-1, 1))
        if k != turned:
            out[j.dof] = Mounting(j.direction, float(j.zero_offset + error))
        else:
            middle = sum(j.position_limits) / 2
            out[j.dof] = Mounting(-j.direction, float(j.zero_offset + 2 * j.direction * j.gear_ratio * middle + error))
    return out


class Store:
    """The bench's JSON file: {"format", "devices": {dof: {"kind", "memory"}}, "mounting": {dof:
    {"direction", "zero_offset"}}}. Missing: an empty store, written at first save."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self.devices: dict[str, dict] = {}
        self.mounting: dict[str, Mounting] = {}
        if not self.path.exists():
            return
        try:
            data = json.loads(self.path.read_text())
            if data.get("format") != FORMAT:
                raise InputError(f"format {data.get('format')!r}, not {FORMAT}")
            self.devices = {dof: {"kind": str(d["kind"]), "memory": dict(d["memory"])}
                            for dof, d in data.get("devices", {}).items()}
            self.mounting = {dof: Mounting(int(m["direction"]), float(m["zero_offset"]))
                             for dof, m in data.get("mounting", {}).items()}
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as err:
            raise InputError(f"the bench's store {self.path}: {err}") from None

    def memory(self, dof: str, kind: str) -> dict | None:
        """The memory the store holds for the device in `dof`'s slot, or None."""
        held = self.devices.get(dof)
        if held is None:
            return None
        if held["kind"] != kind:
            raise InputError(f"the bench's store {self.path}: {dof} holds a {held['kind']} device, "
                             f"the configuration a {kind} one")
        return held["memory"]

    def record(self, dof: str, kind: str, memory: dict) -> bool:
        """Note a device's memory; whether it changed."""
        held = {"kind": kind, "memory": memory}
        if self.devices.get(dof) == held:
            return False
        self.devices[dof] = held
        return True

    def save(self) -> None:
        """Write the file whole (a temporary file renamed over it: never half written)."""
        data = {"format": FORMAT, "devices": self.devices,
                "mounting": {dof: {"direction": m.direction, "zero_offset": m.zero_offset}
                             for dof, m in self.mounting.items()}}
        temporary = self.path.with_name(self.path.name + ".tmp")
        temporary.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")
        os.replace(temporary, self.path)


@dataclass
class BenchSetup:
    """A Lab resolved for one robot: each joint's mounting, the connected dofs, the store."""
    bench: Lab
    store: Store | None
    mounting: dict[str, Mounting]
    connected: set[str]

    def device(self, dof: str, kind: str, what: str, fresh: Callable[[], Device], configured: Callable[[], object],
               device_class: type):
        """The device in `dof`'s slot: from the store's memory, else factory-fresh (factory), else as
        the configuration sets it up; the bench's memory items over it. `kind`: its bus kind (the
        store's key), `what`: its kind in words ("CAN motors"), `fresh` / `configured`: make one."""
        held = self.store.memory(dof, kind) if self.store is not None else None
        overrides = self.bench.memory.get(dof)
        if held is None and overrides is None and not self.bench.factory and self.store is None:
            return configured()
        require(device_class, what)
        device = fresh() if self.bench.factory else configured()
        if held is not None:
            device.restore(held)
        if overrides:
            device.restore(dict(overrides))
        return device

    def attach(self, devices: Mapping[str, Device], kinds: Mapping[str, str]) -> None:
        """Record every device's memory and the mounting in the store, written now and whenever a
        device's memory changes from now on."""
        if self.store is None:
            return
        store = self.store
        store.mounting = dict(self.mounting)
        for dof, device in devices.items():
            store.record(dof, kinds[dof], device.nonvolatile())

            def changed(device, dof=dof):
                if store.record(dof, kinds[dof], device.nonvolatile()):
                    store.save()
            device.on_nonvolatile = changed
        store.save()
