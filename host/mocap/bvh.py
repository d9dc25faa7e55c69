"""BVH motion capture files: read and write.

A BVH file has a HIERARCHY (ROOT, JOINT and End Site blocks, each with an OFFSET from its parent
in the parent's rest frame and, for joints, CHANNELS) and a MOTION section (`Frames:`,
`Frame Time:`, then one line of channel values per frame). Rotation channels are degrees about
the joint's own axes, intrinsic in the order listed: `Zrotation Xrotation Yrotation` is
R = Rz·Rx·Ry, and the order may differ from joint to joint. Positions are in the file's unit,
which the file does not state. All channels zero is the rest pose the OFFSETs describe.

What real files do and this reader accepts: CRLF line ends, tabs, a header that declares fewer
frames than the file holds (all are read, with a warning) or more (those present are read, with
a warning). Anything else — a NaN, a line with the wrong number of values, an unknown channel —
raises BvhError, one line naming the file and line. So do numbers no capture has, which would
otherwise overflow downstream or fill the memory: a rate outside MIN_RATE_HZ to MAX_RATE_HZ (a
clip is resampled at its own rate: 0.25 s at 1e9 frames a second is 19 GiB of samples), an OFFSET
or a position past MAX_LENGTH units (a kilometre in millimetres; its square must stay a double).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import ServodynError

ROTATIONS = ("Xrotation", "Yrotation", "Zrotation")
POSITIONS = ("Xposition", "Yposition", "Zposition")
AXIS_INDEX = {"X": 0, "Y": 1, "Z": 2}
MIN_RATE_HZ = 1.0            # frames a second: keyframes a second apart at the slowest
MAX_RATE_HZ = 10_000.0       # beyond any motion capture system (optical ones reach 2 kHz)
MAX_LENGTH = 1e6             # file units: no skeleton's bone or position in any unit is longer


class BvhError(ServodynError, ValueError):
    """A BVH file that cannot be used; the message names the file and line."""


@dataclass
class Joint:
    name: str
    parent: int                      # index of the parent joint, -1 for the root
    offset: np.ndarray               # (3,) from the parent, in the parent's rest frame (file unit)
    channels: tuple[str, ...]        # as listed, e.g. ("Zrotation", "Xrotation", "Yrotation")
    column: int                      # its first channel's column in the motion table
    end_site: np.ndarray | None = None   # offset of its End Site, if it has one

    @property
    def order(self) -> str:
        """The rotation channels' axes in the listed order, e.g. 'ZXY' ('' when it has none)."""
        return "".join(c[0] for c in self.channels if c in ROTATIONS)


@dataclass
class Clip:
    joints: list[Joint]
    frame_time: float                # s
    motion: np.ndarray               # (frames, channels), as in the file (degrees, file unit)
    warnings: list[str] = field(default_factory=list)
    source: str = ""

    @property
    def frames(self) -> int:
        return len(self.motion)

    @property
    def rate(self) -> float:
        return 1.0 / self.frame_time

    @property
    def duration(self) -> float:
        """Time of the last frame, the first at 0 (s)."""
        return (self.frames - 1) * self.frame_time

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    def index(self, name: str) -> int:
        return self.names.index(name)

    def children(self, i: int) -> list[int]:
        return [k for k, j in enumerate(self.joints) if j.parent == i]

    def local_rotations(self, i: int, frames=slice(None)) -> np.ndarray:
        """(F, 3, 3) rotations of joint i relative to its parent, channel order intrinsic."""
        joint = self.joints[i]
        values = self.motion[frames]
        R = np.broadcast_to(np.eye(3), (len(values), 3, 3)).copy()
        for k, channel in enumerate(joint.channels):
            if channel in ROTATIONS:
                R = R @ axis_rotations(channel[0], np.radians(values[:, joint.column + k]))
        return R

    def rest_positions(self) -> np.ndarray:
        """(joints, 3) positions of the joints in the rest pose, the root at its OFFSET."""
        p = np.zeros((len(self.joints), 3))
        for i, joint in enumerate(self.joints):
            p[i] = joint.offset + (p[joint.parent] if joint.parent >= 0 else 0.0)
        return p

    def with_motion(self, motion: np.ndarray) -> "Clip":
        return Clip(self.joints, self.frame_time, np.asarray(motion, dtype=float), list(self.warnings), self.source)


def axis_rotations(axis: str, angles: np.ndarray) -> np.ndarray:
    """(F, 3, 3) rotations by `angles` (rad) about the coordinate axis 'X', 'Y' or 'Z'."""
    c, s = np.cos(angles), np.sin(angles)
    R = np.zeros((len(angles), 3, 3))
    i = AXIS_INDEX[axis]
    j, k = (i + 1) % 3, (i + 2) % 3
    R[:, i, i] = 1.0
    R[:, j, j] = c
    R[:, k, k] = c
    R[:, k, j] = s
    R[:, j, k] = -s
    return R


# ---------------------------------------------------------------------------- reading

def read_bvh(path: str | Path) -> Clip:
    """The clip in a BVH file; BvhError (one line) for anything it cannot use."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as err:
        raise BvhError(f"{path}: cannot read ({err.strerror})") from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        try:
            text = raw.decode("latin-1")
        except UnicodeDecodeError:
            raise BvhError(f"{path}: not a text file") from None
    return parse_bvh(text, str(path))


def parse_bvh(text: str, source: str = "<bvh>") -> Clip:
    lines = text.splitlines()        # \n, \r\n and \r alike
    reader = _Lines(lines, source)
    joints: list[Joint] = []
    reader.expect("HIERARCHY")
    stack: list[int] = []            # open blocks: joint index, or -2 for an End Site
    columns = 0
    word, rest = reader.next_words()
    if word != "ROOT":
        reader.fail(f"expected ROOT, got '{word}'")
    while True:
        if word in ("ROOT", "JOINT"):
            if word == "ROOT" and stack:
                reader.fail("ROOT inside another joint")
            if word == "JOINT" and (not stack or stack[-1] == -2):
                reader.fail("JOINT outside a joint" if not stack else "JOINT inside an End Site")
            name = " ".join(rest)
            if not name:
                reader.fail(f"{word} without a name")
            if name in (j.name for j in joints):
                reader.fail(f"joint '{name}' is named twice")
            reader.expect("{")
            offset = reader.offset()
            channels = reader.channels()
            joints.append(Joint(name, stack[-1] if stack else -1, offset, channels, columns))
            columns += len(channels)
            stack.append(len(joints) - 1)
        elif word == "End" and rest[:1] == ["Site"]:
            if not stack or stack[-1] == -2:
                reader.fail("End Site outside a joint")
            reader.expect("{")
            joints[stack[-1]].end_site = reader.offset()
            stack.append(-2)
        elif word == "}":
            if not stack:
                reader.fail("'}' without an open block")
            stack.pop()
            if not stack:
                word, rest = reader.next_words()
                if word == "ROOT":
                    reader.fail("a second ROOT (one skeleton per file)")
                if word != "MOTION":
                    reader.fail(f"expected MOTION after the hierarchy, got '{word}'")
                break
        else:
            reader.fail(f"expected JOINT, End Site or '}}', got '{' '.join([word, *rest])}'")
        word, rest = reader.next_words()
    frames = reader.labelled("Frames:", int)
    if frames < 1:
        reader.fail(f"Frames: {frames}: a clip needs at least one frame")
    frame_time = reader.labelled("Frame Time:", float)
    if not (math.isfinite(frame_time) and frame_time > 0):
        reader.fail(f"Frame Time: {frame_time:g}: must be a positive number of seconds")
    if not 1 / MAX_RATE_HZ <= frame_time <= 1 / MIN_RATE_HZ:
        reader.fail(f"Frame Time: {frame_time:g} s is {1 / frame_time:.3g} frames a second; a clip has from "
                    f"{MIN_RATE_HZ:g} to {MAX_RATE_HZ:g}")
    motion, start = reader.motion_rows(columns)
    positions = [j.column + k for j in joints for k, c in enumerate(j.channels) if c in POSITIONS]
    far = np.flatnonzero((np.abs(motion[:, positions]) > MAX_LENGTH).any(axis=1))
    if len(far):
        reader.fail(f"frame {far[0] + 1}: a position beyond {MAX_LENGTH:g} units, no capture's", line=start + far[0])
    warnings = []
    if len(motion) > frames:
        warnings.append(f"the header declares {frames} frames, the file holds {len(motion)}: all "
                        f"{len(motion)} read")
    elif len(motion) < frames:
        if len(motion) == 0:
            reader.fail(f"Frames: {frames}, but no frame follows", line=start)
        warnings.append(f"the header declares {frames} frames, the file holds {len(motion)} (cut short?): "
                        f"the {len(motion)} present read")
    return Clip(joints, frame_time, motion, warnings, source)


class _Lines:
    """The file's lines, read one non-blank line at a time, with errors naming the line."""

    def __init__(self, lines: list[str], source: str):
        self.lines, self.source, self.i = lines, source, 0

    def fail(self, message: str, line: int | None = None):
        raise BvhError(f"{self.source}: line {line or self.i}: {message}")

    def next_words(self) -> tuple[str, list[str]]:
        while self.i < len(self.lines):
            words = self.lines[self.i].split()
            self.i += 1
            if words:
                return words[0], words[1:]
        raise BvhError(f"{self.source}: the file ends inside the hierarchy (line {self.i})")

    def expect(self, word: str):
        got, rest = self.next_words()
        if got != word or rest:
            self.fail(f"expected '{word}', got '{' '.join([got, *rest])}'")

    def numbers(self, words: list[str], what: str) -> list[float]:
        try:
            values = [float(w) for w in words]
        except ValueError:
            self.fail(f"{what}: '{' '.join(words)}' are not numbers")
        if not all(math.isfinite(v) for v in values):
            self.fail(f"{what}: a value is not a finite number")
        return values

    def offset(self) -> np.ndarray:
        word, rest = self.next_words()
        if word != "OFFSET" or len(rest) != 3:
            self.fail(f"expected 'OFFSET x y z', got '{' '.join([word, *rest])}'")
        values = np.array(self.numbers(rest, "OFFSET"))
        if np.abs(values).max() > MAX_LENGTH:
            self.fail(f"OFFSET {' '.join(rest)}: beyond {MAX_LENGTH:g} units, no skeleton's bone")
        return values

    def channels(self) -> tuple[str, ...]:
        word, rest = self.next_words()
        if word != "CHANNELS" or not rest:
            self.fail(f"expected 'CHANNELS n ...', got '{' '.join([word, *rest])}'")
        try:
            n = int(rest[0])
        except ValueError:
            self.fail(f"CHANNELS: '{rest[0]}' is not a count")
        names = tuple(rest[1:])
        if n != len(names):
            self.fail(f"CHANNELS {n}, but {len(names)} channel names follow")
        for name in names:
            if name not in ROTATIONS + POSITIONS:
                self.fail(f"unknown channel '{name}' (expected X/Y/Z rotation or position)")
        if len(set(names)) != len(names):
            self.fail("a channel is listed twice")
        return names

    def labelled(self, label: str, kind):
        while self.i < len(self.lines) and not self.lines[self.i].strip():
            self.i += 1
        if self.i >= len(self.lines):
            raise BvhError(f"{self.source}: the file ends before '{label}'")
        line = self.lines[self.i].strip()
        self.i += 1
        if not line.startswith(label):
            self.fail(f"expected '{label} ...', got '{line}'")
        value = line[len(label):].strip()
        try:
            return kind(value)
        except ValueError:
            self.fail(f"{label} '{value}' is not a {'whole ' if kind is int else ''}number")

    def motion_rows(self, columns: int) -> tuple[np.ndarray, int]:
        """The frames, (F, columns); a blank line at the end is allowed, one inside is not."""
        start = self.i + 1
        rows = self.lines[self.i:]
        while rows and not rows[-1].strip():
            rows.pop()
        try:
            values = np.array(" ".join(rows).split(), dtype=float)
        except ValueError:
            values = None
        if values is None or columns == 0 or values.size != columns * len(rows) or not np.all(np.isfinite(values)):
            self.first_bad_row(rows, columns, start)
        return values.reshape(len(rows), columns), start

    def first_bad_row(self, rows: list[str], columns: int, start: int):
        if columns == 0:
            self.fail("the hierarchy has no channels", line=start - 1)
        for r, row in enumerate(rows):
            words = row.split()
            line = start + r
            if len(words) != columns:
                self.fail(f"frame {r + 1} has {len(words)} values, the hierarchy has {columns} channels", line=line)
            for c, word in enumerate(words):
                try:
                    value = float(word)
                except ValueError:
                    self.fail(f"frame {r + 1}, channel {c + 1}: '{word}' is not a number", line=line)
                if not math.isfinite(value):
                    self.fail(f"frame {r + 1}, channel {c + 1}: '{word}' is not a finite number", line=line)
        self.fail("the frames do not match the hierarchy", line=start)


# ---------------------------------------------------------------------------- writing

def format_bvh(clip: Clip, decimals: int = 6) -> str:
    """The clip as BVH text (tabs, LF line ends), values with `decimals` decimals."""
    out = ["HIERARCHY"]
    fmt = f"{{:.{decimals}f}}"

    def number(v):
        text = fmt.format(v)
        return "0" + text[2:] if text.startswith("-0") and float(text) == 0 else text   # no '-0.000'

    def offset(v):
        return " ".join(number(x) for x in v)

    def block(i: int, depth: int):
        joint = clip.joints[i]
        pad = "\t" * depth
        out.append(f"{pad}{'ROOT' if joint.parent < 0 else 'JOINT'} {joint.name}")
        out.append(f"{pad}{{")
        out.append(f"{pad}\tOFFSET {offset(joint.offset)}")
        out.append(f"{pad}\tCHANNELS {len(joint.channels)} {' '.join(joint.channels)}".rstrip())
        for child in clip.children(i):
            block(child, depth + 1)
        if joint.end_site is not None:
            out.extend([f"{pad}\tEnd Site", f"{pad}\t{{", f"{pad}\t\tOFFSET {offset(joint.end_site)}", f"{pad}\t}}"])
        out.append(f"{pad}}}")

    block(0, 0)
    out += ["MOTION", f"Frames: {clip.frames}", f"Frame Time: {clip.frame_time:.7g}"]
    for row in clip.motion:
        out.append(" ".join(number(v) for v in row))
    return "\n".join(out) + "\n"


def write_bvh(path: str | Path, clip: Clip, decimals: int = 6) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(format_bvh(clip, decimals))
