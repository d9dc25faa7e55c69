"""Contact for the simulated plant, as data: a push on a body (`Push`) and obstacles its solids can hit
(`Plane`, `Sphere`). The simulator (sim/contact.py) applies them; a run carries them here, below the
loop and the simulator both (`servodyn swing --contact ... --obstacle ...`, RunOptions).

    Push("r_hand", (0.0, 0.0, -10.0), start=1.2)          # 10 N down at the hand's centre of mass
    Plane((0.0, 0.0, 1.0), -0.45)                         # a table top 0.45 m below the base's origin
    Sphere((0.3, -0.2, -0.3), 0.1, stiffness=75e3)        # a hand-stiff ball

Units: N, m, s, N/m; the world frame is the model's base frame. A push acts from `start` for
`duration` seconds: in a run `start` counts from the motion's start (homing excluded), on the
simulator's own clock from when the caller says (sim's `schedule_push(push, origin)`). An obstacle is
there from the start. Each is a spring–damper of `stiffness` along its normal (sim/contact.py gives
the damping); its default is ISO/TS 15066 Table A.3's for a lower arm (40 N/mm), a person's forearm
in the arm's way, between the hand's 75 and the chest's 25 N/mm.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

from ..errors import InputError

PUSH_DURATION = 0.3          # s a push lasts unless told
OBSTACLE_STIFFNESS = 40e3    # N/m: ISO/TS 15066 Table A.3, lower arm (40 N/mm)
MAX_STIFFNESS = 1e6          # N/m (1000 N/mm): the stiffest contact the plant integrates (sim/contact.py
                             # cuts its step into more pieces as the stiffness grows)
MAX_FORCE = 1e4              # N: a push larger than this is a typing error
MAX_DISTANCE = 100.0         # m: an obstacle farther than this from the arm is a typing error


def _finite(values, what: str) -> tuple[float, ...]:
    out = tuple(float(v) for v in values)
    if not all(math.isfinite(v) for v in out):
        raise InputError(f"{what} must be finite numbers, got {', '.join(map(str, values))}")
    return out


def _stiffness(k: float) -> float:
    if not (math.isfinite(k) and 0 < k <= MAX_STIFFNESS):
        raise InputError(f"an obstacle's stiffness is a positive number of N/m up to {MAX_STIFFNESS:g}, got {k:g}")
    return float(k)


@dataclass(frozen=True)
class Push:
    """A force (N, world frame) at `body`'s centre of mass from `start` for `duration` s."""
    body: str
    force: tuple[float, float, float]
    start: float
    duration: float = PUSH_DURATION

    def __post_init__(self):
        force = _finite(self.force, "a push's force (N)")
        if len(force) != 3 or max(map(abs, force)) > MAX_FORCE:
            raise InputError(f"a push's force is three numbers of N each up to {MAX_FORCE:g}, got {self.force}")
        object.__setattr__(self, "force", force)
        if not (math.isfinite(self.start) and self.start >= 0):
            raise InputError(f"a push starts at 0 s or later, got {self.start:g}")
        if not (math.isfinite(self.duration) and self.duration > 0):
            raise InputError(f"a push lasts a positive number of seconds, got {self.duration:g}")

    @property
    def end(self) -> float:
        return self.start + self.duration


@dataclass(frozen=True)
class Plane:
    """Points x with normal·x < offset are inside (a half-space: a table top, a wall); the normal
    is kept unit length (a longer one scales the offset with it: the same half-space)."""
    normal: tuple[float, float, float]
    offset: float
    stiffness: float = OBSTACLE_STIFFNESS

    def __post_init__(self):
        normal = _finite(self.normal, "a plane's normal")
        length = math.sqrt(sum(v * v for v in normal))
        if len(normal) != 3 or length < 1e-9:
            raise InputError(f"a plane's normal is three numbers, not all 0, got {self.normal}")
        offset = _finite([self.offset], "a plane's offset (m)")[0] / length
        if abs(offset) > MAX_DISTANCE:
            raise InputError(f"a plane {offset:g} m from the base is out of the arm's reach "
                             f"(at most {MAX_DISTANCE:g} m)")
        object.__setattr__(self, "normal", tuple(v / length for v in normal))
        object.__setattr__(self, "offset", offset)
        object.__setattr__(self, "stiffness", _stiffness(self.stiffness))


@dataclass(frozen=True)
class Sphere:
    """Points closer than `radius` to `centre` are inside (a ball, a head)."""
    centre: tuple[float, float, float]
    radius: float
    stiffness: float = OBSTACLE_STIFFNESS

    def __post_init__(self):
        centre = _finite(self.centre, "a sphere's centre (m)")
        if len(centre) != 3 or max(map(abs, centre)) > MAX_DISTANCE:
            raise InputError(f"a sphere's centre is three numbers of m each up to {MAX_DISTANCE:g}, got {self.centre}")
        if not (math.isfinite(self.radius) and 0 < self.radius <= MAX_DISTANCE):
            raise InputError(f"a sphere's radius is a positive number of m, got {self.radius:g}")
        object.__setattr__(self, "centre", centre)
        object.__setattr__(self, "radius", float(self.radius))
        object.__setattr__(self, "stiffness", _stiffness(self.stiffness))


OBSTACLES = {"plane": Plane, "sphere": Sphere}


def to_dict(item) -> dict:
    """A push or an obstacle as JSON-able data (`from_dict` reads it back)."""
    kind = "push" if isinstance(item, Push) else next(k for k, c in OBSTACLES.items() if isinstance(item, c))
    return {"kind": kind, **asdict(item)}


def from_dict(data: dict):
    kinds = {"push": Push, **OBSTACLES}
    fields = dict(data)
    kind = fields.pop("kind", None)
    if kind not in kinds:
        raise InputError(f"a contact is one of {', '.join(kinds)}, got {kind!r}")
    return kinds[kind](**fields)


def check_contacts(model, pushes, obstacles, simulated: bool, native: bool = False) -> None:
    """InputError (one line) unless every push names a body of `model` and the run's plant is this
    process's simulator (`simulated`): a real arm, or a simulator in another process, takes none;
    nor does the native loop take a push (the swing's start is its own to know)."""
    if not (pushes or obstacles):
        return
    if not simulated:
        raise InputError("--contact and --obstacle act on the simulated plant a run starts itself: not on a "
                         "real port (a `servodyn sim` in another process takes its own --obstacle)")
    if native and pushes:
        raise InputError("--contact starts from the swing's start, which the native loop keeps to itself: "
                         "push in the Python loop (an --obstacle works with --native)")
    for push in pushes:
        if push.body not in model.body_names:
            raise InputError(f"a push on {push.body!r}: '{model.name}' has no such body (bodies: "
                             f"{', '.join(model.body_names)})")
