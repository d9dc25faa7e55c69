"""Captured human motion: BVH files (`bvh`), what their skeletons are (`skeleton`) and the arm's
motion retargeted onto a model (`retarget`). Below the HAL and beside it: it needs the model and
the trajectory format only."""

from .bvh import BvhError, Clip, Joint, read_bvh, write_bvh
from .retarget import ArmTarget, RetargetError, retarget
from .skeleton import SkeletonError, find_arms, guess_axes

__all__ = ["ArmTarget", "BvhError", "Clip", "Joint", "RetargetError", "SkeletonError", "find_arms", "guess_axes",
           "read_bvh", "retarget", "write_bvh"]
