"""What a BVH skeleton is, guessed from the file: its arms (by name tables), its axes, its unit and
its rest frame.

- Arms: names.toml beside this file has a table per source (CMU/cgspeed, Mixamo, Motive, Xsens);
  a file named otherwise takes a TOML map of its own (`read_map`). A table matches when every role
  is found along one chain: thorax, optional clavicle, upper arm, forearm, hand.
- Axes: up is the coordinate axis nearest the spine (root to thorax), left the one from the right
  arm to the left; forward = left × up. `axes` is the matrix A that turns a vector in the file's
  axes into servodyn's (x forward, y left, z up). The feet, where the file has toes, check that
  the arm named right is on the right.
- Unit: from the skeleton's height, nearest 1.7 m among the units files use (UNITS).
- Rest: frame 0 of the cgspeed files is a T-pose: it is dropped when the first step is far larger
  than the others (REST_STEP_RATIO times the median and over REST_STEP_MIN).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import ServodynError
from ..model.files import read_toml
from ..model.rotations import rotation_angle
from .bvh import Clip

NAMES_FILE = Path(__file__).with_name("names.toml")
ROLES = ("thorax", "clavicle", "upper_arm", "forearm", "hand")
SIDES = ("right", "left")

# metres per file unit; CMU's cgspeed files keep the ASF unit of 1/0.45 inch
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254, "cmu": 0.056444}
TYPICAL_HEIGHT_M = 1.7
REST_STEP_RATIO = 10.0
REST_STEP_MIN = math.radians(20.0)


class SkeletonError(ServodynError, ValueError):
    """A skeleton the retargeting cannot use: one line that says what is missing."""


@dataclass(frozen=True)
class ArmChain:
    side: str
    source: str                  # the name table (or map file) that found it
    thorax: int
    clavicle: int | None
    upper_arm: int
    forearm: int
    hand: int

    def path(self, clip: Clip, to: int) -> list[int]:
        """The joints from below the thorax down to `to`, in order."""
        chain = []
        while to != self.thorax:
            chain.append(to)
            to = clip.joints[to].parent
        return chain[::-1]

    def names(self, clip: Clip) -> dict:
        return {role: clip.joints[getattr(self, role)].name if getattr(self, role) is not None else None
                for role in ROLES}


def _matches(joint: str, name: str) -> bool:
    joint, name = joint.lower(), name.lower()
    return joint == name or joint.endswith(":" + name) or joint.endswith("_" + name)


def _ancestors(clip: Clip, i: int) -> list[int]:
    out = []
    while clip.joints[i].parent >= 0:
        i = clip.joints[i].parent
        out.append(i)
    return out


def _find(clip: Clip, candidates: list[str]) -> list[int]:
    return [i for name in candidates for i, j in enumerate(clip.joints) if _matches(j.name, name)]


def _chain(clip: Clip, side: str, source: str, roles: dict[str, list[str]]) -> ArmChain | None:
    """The chain whose joints carry these names, linked parent to child, or None."""
    for hand in _find(clip, roles["hand"]):
        forearm = clip.joints[hand].parent
        if forearm < 0 or forearm not in _find(clip, roles["forearm"]):
            continue
        upper = clip.joints[forearm].parent
        if upper < 0 or upper not in _find(clip, roles["upper_arm"]):
            continue
        above = _ancestors(clip, upper)
        thorax = next((i for i in _find(clip, roles["thorax"]) if i in above), None)
        if thorax is None:
            continue
        between = above[:above.index(thorax)]
        clavicle = next((i for i in _find(clip, roles.get("clavicle", [])) if i in between), None)
        return ArmChain(side, source, thorax, clavicle, upper, forearm, hand)
    return None


def name_tables() -> list[dict]:
    return read_toml(NAMES_FILE, SkeletonError)["source"]


def read_map(path: str | Path) -> dict[str, dict[str, list[str]]]:
    """A user's map: [right] and/or [left] tables naming the roles (clavicle optional)."""
    path = Path(path)
    try:
        data = read_toml(path, SkeletonError)
    except FileNotFoundError:
        raise SkeletonError(f"{path}: no such file (a name map, TOML)") from None
    sides = {side: data[side] for side in SIDES if isinstance(data.get(side), dict)}
    if not sides or set(data) - set(SIDES):
        raise SkeletonError(f"{path}: expected [right] and/or [left] tables of {', '.join(ROLES)}")
    out = {}
    for side, table in sides.items():
        unknown = set(table) - set(ROLES)
        missing = [r for r in ROLES if r != "clavicle" and not isinstance(table.get(r), str)]
        if unknown or missing:
            what = f"unknown role '{sorted(unknown)[0]}'" if unknown else f"no joint named for '{missing[0]}'"
            raise SkeletonError(f"{path}: [{side}]: {what} (roles: {', '.join(ROLES)}; clavicle optional)")
        out[side] = {role: [table[role]] for role in ROLES if role in table}
    return out


def find_arms(clip: Clip, map_file: str | Path | None = None) -> dict[str, ArmChain]:
    """The arm chains found, by side; the user's map replaces the tables."""
    found = {}
    if map_file is not None:
        for side, roles in read_map(map_file).items():
            chain = _chain(clip, side, str(map_file), roles)
            if chain is None:
                names = ", ".join(f"{r} '{v[0]}'" for r, v in roles.items())
                raise SkeletonError(f"{map_file}: [{side}]: no chain {names} in {clip.source} (each the parent "
                                    "of the next, the thorax above)")
            found[side] = chain
        return found
    for table in name_tables():
        for side in SIDES:
            if side in found:
                continue
            word = table["sides"][side]
            roles = {role: [n.replace("{side}", word) for n in table.get(role, [])] for role in ROLES}
            chain = _chain(clip, side, table["name"], roles)
            if chain is not None:
                found[side] = chain
    return found


@dataclass(frozen=True)
class Axes:
    A: np.ndarray                 # servodyn vector = A @ file vector
    up: str                       # the file's up axis, e.g. '+Y'
    forward: str


def _axis_name(v) -> str:
    i = int(np.argmax(np.abs(v)))
    return ("+" if v[i] > 0 else "-") + "XYZ"[i]


def _snap(v, exclude=None) -> np.ndarray:
    v = np.array(v, dtype=float)
    if exclude is not None:
        v[int(np.argmax(np.abs(exclude)))] = 0.0
    i = int(np.argmax(np.abs(v)))
    out = np.zeros(3)
    out[i] = math.copysign(1.0, v[i])
    return out


def guess_axes(clip: Clip, arms: dict[str, ArmChain]) -> tuple[Axes, list[str]]:
    """The file's axes from its rest pose: up along the spine, left from the arms (or from the
    one arm: it points away from the thorax to its side). Warnings when the feet disagree."""
    p = clip.rest_positions()
    warnings = []
    any_arm = next(iter(arms.values()))
    spine = p[any_arm.thorax] - p[0]
    if np.linalg.norm(spine) < 1e-9:
        spine = p.max(0) - p.min(0)
    up = _snap(spine)
    if "right" in arms and "left" in arms:
        left = p[arms["left"].upper_arm] - p[arms["right"].upper_arm]
    else:
        outward = p[any_arm.forearm] - p[any_arm.thorax]
        left = outward if any_arm.side == "left" else -outward
    if np.linalg.norm(left - (left @ up) * up) < 1e-9:
        raise SkeletonError(f"{clip.source}: the arms' rest pose gives no left-right direction (both arms on the "
                            "spine)")
    left = _snap(left, exclude=up)
    forward = np.cross(left, up)
    A = np.stack([forward, left, up])
    toes = [i for i, j in enumerate(clip.joints) if "toe" in j.name.lower() and j.parent >= 0]
    if toes:
        feet = sum(p[i] - p[clip.joints[i].parent] for i in toes)
        feet = feet - (feet @ up) * up
        if np.linalg.norm(feet) > 1e-9 and feet @ forward < -0.5 * np.linalg.norm(feet):
            warnings.append("the toes point backwards with the arms as named: the file's left and right may be "
                            "swapped (the names are kept)")
    return Axes(A, _axis_name(up), _axis_name(forward)), warnings


def skeleton_height(clip: Clip, up_axis: np.ndarray) -> float:
    """The rest skeleton's extent along the up axis, end sites included (file unit)."""
    p = clip.rest_positions()
    ends = [p[i] + j.end_site for i, j in enumerate(clip.joints) if j.end_site is not None]
    heights = np.concatenate([p, np.array(ends).reshape(-1, 3)]) @ up_axis
    return float(heights.max() - heights.min())


def guess_unit(height: float) -> str:
    """The unit that makes the skeleton nearest TYPICAL_HEIGHT_M tall."""
    if not height > 0:
        return "m"
    return min(UNITS, key=lambda u: abs(math.log(height * UNITS[u] / TYPICAL_HEIGHT_M)))


def segment_rotations(clip: Clip, chain: ArmChain, frames=slice(None)) -> dict[str, np.ndarray]:
    """(F, 3, 3) rotations of the upper arm, forearm and hand relative to the thorax (the clavicle,
    where there is one, folded into the upper arm), in the file's axes."""
    out = {}
    R = None
    for joint in chain.path(clip, chain.hand):
        local = clip.local_rotations(joint, frames)
        R = local if R is None else R @ local
        for role in ("upper_arm", "forearm", "hand"):
            if joint == getattr(chain, role):
                out[role] = R
    return out


def rest_frame(clip: Clip, chain: ArmChain) -> tuple[bool, float, float]:
    """(is frame 0 a rest pose to drop, its step, the median step) over the arm's segments (rad)."""
    if clip.frames < 3:
        return False, 0.0, 0.0
    rotations = segment_rotations(clip, chain)
    steps = np.max([rotation_angle(np.einsum("fji,fjk->fik", R[:-1], R[1:])) for R in rotations.values()], axis=0)
    first, median = float(steps[0]), float(np.median(steps[1:]))
    return bool(first > REST_STEP_RATIO * median and first > REST_STEP_MIN), first, median
