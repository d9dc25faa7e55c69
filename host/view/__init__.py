"""The arm in 3-D in a browser page (viser: a Python-served three.js page), as `servodyn view` and
`servodyn swing --view` serve it.

The arm is drawn from its own solids — the paper's primitives and, on the replicas, the servos'
housings (model.shapes) — each body posed by the model's forward kinematics (`user_poses`, the
model file's frames). What the page does:

  play     a motion (keyframes, a trajectory CSV) or a logged run (swing_log.csv): the planned arm
           as a ghost, the measured arm solid; angle, tracking error and torque plots that follow
           the time cursor; at each joint a ball coloured by its torque's share of the servo's
           limit (the validator's torque-speed envelope; without a configuration, of the
           motion's own peak)
  shape    a keyframe motion's keyframes edited with the page's controls (the angle of each dof,
           the keyframe's time) or by dragging the hand: the arm, the torque profile (the motion's
           inverse dynamics in one batched call into the C core) and the validator's verdict
           follow at once; saved as a keyframe file
  live     a run's every tick handed to `LiveFeed.observe`, which only keeps the latest; a thread
           of the viewer's own draws it at PUBLISH_HZ

Where each part is:

  timeline.py  the subject (a configuration or a model) and the `Timeline` shown — a motion's, a
               trajectory's or a logged run's samples, torques and shares of the limits; `ViewError`
  drawing.py   the arm's solids in the scene (`ArmDrawing`) and the captured arm (`SourceOverlay`)
  app.py       `Viewer`: the viser server and its page, the player and the plots
  editor.py    `MotionEditor`: the keyframes in the page's controls, torques and verdict on each edit
  gizmo.py     `HandGizmo`: the hand dragged by inverse kinematics (its events handled by one worker)
  live.py      `LiveFeed`: the loop's observer and the thread that draws it
  page.py      `open_view` and `live_viewer`: a page for a subject with what it plays

Threads: viser runs the page's callbacks in a thread pool; the player, the hand's worker and the
live feed are threads of the viewer's own. Each change to the keyframes or the cursor is made
whole under `Viewer.lock`.
"""

from .app import Viewer
from .editor import MotionEditor
from .gizmo import HandGizmo
from .live import PUBLISH_HZ, LiveFeed
from .page import DEFAULT_MOTION, live_viewer, open_view
from .timeline import Timeline, ViewError, load_subject, log_timeline, share_rgb

__all__ = ["DEFAULT_MOTION", "PUBLISH_HZ", "HandGizmo", "LiveFeed", "MotionEditor", "Timeline", "ViewError", "Viewer",
           "live_viewer", "load_subject", "log_timeline", "open_view", "share_rgb"]
