"""A model's arm motion as a BVH clip that animation tools open and `retarget` reads back.

The skeleton is a standing figure in the CMU/cgspeed naming (Hips, Spine1, RightShoulder, RightArm,
RightForeArm, RightHand; the left arm, legs and head at rest), Y up, Z forward, X to the subject's
left, its arm lengths the model's. The arm moves; everything else stays at rest. The rest pose
(all channels zero) is the model's hanging arm ("hang") or a T-pose ("tpose", as CMU files have).
Each segment's rotation is the inverse of retarget's reading with no twist, so a round trip
returns the angles to the file's precision."""

from __future__ import annotations

import numpy as np

from .angles import smallest_rotation, split3
from .bvh import POSITIONS, Clip, Joint
from .retarget import ArmTarget
from .skeleton import UNITS

FILE_AXES = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])   # servodyn = A @ file (Y up, Z fwd)
REST_POSES = ("hang", "tpose")
ORDERS = ("XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX")

# the figure around the arm (m, servodyn axes): hips to thorax, thorax to each shoulder, hip
# joints, thigh, shin, foot; a 1.7 m figure with the model's arm
SPINE = np.array([0.0, 0.0, 0.45])
SHOULDER = np.array([0.0, 0.19, 0.05])
HEAD = np.array([0.0, 0.0, 0.30])
HIP = np.array([0.0, 0.09, -0.05])
THIGH, SHIN = np.array([0.0, 0.0, -0.45]), np.array([0.0, 0.0, -0.43])
FOOT, TOE = np.array([0.05, 0.0, -0.07]), np.array([0.12, 0.0, 0.0])


def _rotation_channels(order: str) -> tuple[str, ...]:
    return tuple(f"{axis}rotation" for axis in order)


def euler_channels(R: np.ndarray, order: str) -> np.ndarray:
    """(F, 3) degrees of the intrinsic rotations about `order`'s axes that make R, each frame's
    branch the one nearest the frame before (angles in (-180, 180])."""
    e = np.eye(3)
    sets = split3(R, *(e["XYZ".index(a)] for a in order))
    out = np.empty((len(R), 3))
    previous = np.zeros(3)
    for i in range(len(R)):
        cost = [np.abs((s[i] - previous + np.pi) % (2 * np.pi) - np.pi).sum() for s in sets]
        out[i] = previous = sets[int(np.argmin(cost))][i]
    return np.degrees(out)


def arm_clip(target: ArmTarget, q: np.ndarray, frame_time: float, orders: dict[str, str] | str = "ZXY",
             unit_name: str = "cm", rest: str = "hang") -> Clip:
    """The clip of the arm at angles q (F, 7), every frame_time s. `orders`: one rotation order for
    every joint or one per joint name (the others ZXY)."""
    if rest not in REST_POSES:
        raise ValueError(f"rest pose '{rest}': expected one of {', '.join(REST_POSES)}")
    scale = 1.0 / UNITS[unit_name]
    to_file = FILE_AXES.T
    upper_len, fore_len = target.lengths
    hand_len = 2 * float(np.linalg.norm(target.hand - target.wrist))
    if rest == "hang":
        upper_dir, fore_dir = target.upper_dir, target.fore_dir
    else:
        upper_dir = fore_dir = np.array([0.0, -1.0, 0.0])
    mirror = np.diag([1.0, -1.0, 1.0])

    def order_of(name):
        if isinstance(orders, str):
            return orders
        return orders.get(name, "ZXY")

    joints: list[Joint] = []
    column = [0]

    def add(name, parent, offset_m, channels=None, end=None):
        channels = channels if channels is not None else _rotation_channels(order_of(name))
        joints.append(Joint(name, parent, to_file @ np.asarray(offset_m) * scale, channels, column[0],
                            None if end is None else to_file @ np.asarray(end) * scale))
        column[0] += len(channels)
        return len(joints) - 1

    hips = add("Hips", -1, np.zeros(3), POSITIONS + _rotation_channels(order_of("Hips")))
    spine = add("Spine1", hips, SPINE)
    add("Head", spine, HEAD * 0.4, end=HEAD * 0.6)
    arm = {}
    for side, flip in (("Right", np.eye(3)), ("Left", mirror)):
        sign = -1.0 if side == "Right" else 1.0
        clavicle = add(f"{side}Shoulder", spine, SHOULDER * [1, sign, 1])
        upper = add(f"{side}Arm", clavicle, np.zeros(3))
        fore = add(f"{side}ForeArm", upper, flip @ upper_dir * upper_len)
        hand = add(f"{side}Hand", fore, flip @ fore_dir * fore_len, end=flip @ fore_dir * hand_len)
        arm[side] = (upper, fore, hand)
    for side, sign in (("Right", -1.0), ("Left", 1.0)):
        hip = add(f"{side}UpLeg", hips, HIP * [1, sign, 1])
        knee = add(f"{side}Leg", hip, THIGH)
        ankle = add(f"{side}Foot", knee, SHIN)
        add(f"{side}ToeBase", ankle, FOOT, end=TOE)

    motion = np.zeros((len(q), column[0]))
    F_upper, F_fore, F_hand = target.rotations(q)
    S_upper = smallest_rotation(target.upper_dir, upper_dir)
    S_fore = smallest_rotation(target.fore_dir, fore_dir)
    # file-axes rotations relative to the thorax: M = Aᵀ F S_restᵀ A
    M = {k: np.einsum("ji,fjk,kl->fil", FILE_AXES, F @ S.T, FILE_AXES)
         for k, F, S in (("upper", F_upper, S_upper), ("fore", F_fore, S_fore), ("hand", F_hand, S_fore))}
    upper, fore, hand = arm["Right"]
    local = {upper: M["upper"], fore: np.einsum("fji,fjk->fik", M["upper"], M["fore"]),
             hand: np.einsum("fji,fjk->fik", M["fore"], M["hand"])}
    for i, R in local.items():
        joint = joints[i]
        motion[:, joint.column:joint.column + 3] = euler_channels(R, joint.order)
    return Clip(joints, float(frame_time), motion, [], "export")

