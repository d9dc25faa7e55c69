"""A page for a subject: `open_view` (a motion to shape, or a trajectory or a logged run to play,
with the captured arm a retargeted motion came from) and `live_viewer` (the arm as a run plays it)."""

from __future__ import annotations

import math
from pathlib import Path

from ..control.motion import DEFAULT_MOTION, builtin_motions, load_motion, motion_path
from ..control.trajectory import TrajectoryError
from ..mocap import BvhError, RetargetError, SkeletonError, find_arms, guess_axes, read_bvh
from ..mocap.retarget import source_arm
from ..model import ModelError
from .app import Viewer
from .drawing import SourceOverlay
from .live import LiveFeed
from .timeline import Timeline, ViewError, load_subject, log_timeline, trajectory_timeline

MAX_SOURCE_FRAMES = 1_000_000   # frames of a captured arm overlaid (a 2.3 h clip at 120 Hz): a clip
                                # whose Frame Time makes more is refused before it is resampled


def open_view(spec: str | None = None, log: str | None = None, motion: str | None = None,
              time_scale: float | None = None, host: str = "127.0.0.1", http_port: int = 8080,
              save_to: Path | None = None, source: str | None = None, say=print) -> Viewer:
    """Serve the page for a configuration or model, with a logged run or a motion loaded; with
    `source` (a BVH clip) the captured arm a retargeted motion CSV came from, overlaid."""
    config, model = load_subject(spec)
    if source is not None and not str(motion or "").lower().endswith(".csv"):
        raise ViewError(f"{source}: a captured clip is overlaid on the motion CSV `servodyn retarget -o` wrote "
                        "from it: give that CSV as the motion")
    timeline = None
    if log is not None:
        timeline = log_timeline(model, config, Path(log))
    motion_obj = None
    nothing_to_play = None             # why there is no Play panel
    default = config.swing_motion if config is not None else DEFAULT_MOTION
    if log is None and motion is None:
        try:                           # the configuration's motion (the forehand), where the model has its dofs
            motion_obj = load_motion(default, model)
        except (TrajectoryError, ModelError) as err:
            nothing_to_play = (f"**No Play panel**: nothing to play. No --motion or --log was given, and the "
                               f"default motion, {default}, does not fit model '{model.name}' "
                               f"({str(err).split(': ', 1)[-1]}). Give `--motion` a keyframe file or a "
                               f"trajectory CSV of this model's dofs, or `--log` a run's folder.")
    elif log is None:
        name = motion
        if str(name).lower().endswith(".csv"):
            timeline = _csv_timeline(model, config, name, time_scale or 1.0)
        else:
            if str(name) not in builtin_motions() and not Path(name).exists():
                raise ViewError(f"{name}: no such file, and not a built-in motion "
                                f"({', '.join(builtin_motions())})")
            try:
                motion_obj = load_motion(name, model)
            except (TrajectoryError, ModelError) as err:
                raise ViewError(str(err)) from None
    if time_scale is None:
        time_scale = config.time_scale_for(default) if config is not None and motion is None else 1.0
    if not (math.isfinite(time_scale) and time_scale > 0):
        raise ViewError(f"the time scale must be a positive number, got {time_scale}")
    overlay = None
    if source is not None and timeline is not None:
        overlay = _source_arm(source, model, float(timeline.t[-1]) / time_scale)
    viewer = Viewer(config, model, host=host, http_port=http_port, say=say)
    if motion_obj is not None:
        viewer.edit(motion_obj, time_scale, save_to or Path("out/view") / f"{motion_obj.name}.toml")
    elif timeline is not None:
        if overlay is not None:
            viewer.source = SourceOverlay(viewer.server, *overlay, time_scale)
        viewer.show_timeline(timeline, f"run {log}" if log else f"{motion} at time scale {time_scale:g}")
    elif nothing_to_play:
        viewer.readout.content = nothing_to_play
    return viewer


def _csv_timeline(model, config, name: str, time_scale: float) -> Timeline:
    try:
        return trajectory_timeline(model, config, motion_path(name, model).at_scale(time_scale))[0]
    except (TrajectoryError, ValueError) as err:
        raise ViewError(str(err)) from None


def _source_arm(source: str, model, duration: float):
    """(times, points) of the captured arm in the clip, on the clock of a motion of `duration` s
    retargeted from it; ViewError (one line) for a clip that cannot be that motion's source."""
    try:
        clip = read_bvh(source)
        frames = duration / clip.frame_time
        if not frames <= MAX_SOURCE_FRAMES:
            raise ViewError(f"{source}: Frame Time {clip.frame_time:g} s makes the {duration:.3g} s motion "
                            f"{frames:.3g} frames of the clip (at most {MAX_SOURCE_FRAMES:.0e} are overlaid)")
        arms = find_arms(clip)
        return source_arm(clip, model, duration, arms, guess_axes(clip, arms)[0] if arms else None)
    except (BvhError, RetargetError, SkeletonError) as err:
        raise ViewError(str(err)) from None


def live_viewer(spec: str | None, host: str = "127.0.0.1", http_port: int = 8080,
                say=print) -> tuple[Viewer, LiveFeed]:
    """The page for a run played live (`servodyn swing --view`), and the feed the loop calls (its
    observer)."""
    config, model = load_subject(spec)
    viewer = Viewer(config, model, host=host, http_port=http_port, say=say)
    return viewer, viewer.live()
