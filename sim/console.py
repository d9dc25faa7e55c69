"""A hand on the simulated bench: a small console over a served simulated robot, so the bring-up
steps a person does by hand (`servodyn calibrate`'s "move it", "put it in its zero pose", "move it
to its stop") can be done on the simulated arm from a terminal.

    console = Console(robot)                    # a SimulatedRobot, or what serves one (its .robot)
    console.do("move elbow 30")                 # one line in, its answer out
    run_console(served, sys.stdin, print)       # line by line until the input ends

Commands (a joint is its dof name or any part of it that names one joint: `elbow`):

    move JOINT DEG     the hand turns the joint to DEG (the model's angle, the configuration's
                       sign) in a second (MOVE_TIME), then holds it there
    push JOINT +|-     the hand takes the joint onto its + or - stop (the model's limit) and holds it
    zero               the hand puts every joint limp under it in the zero pose (every angle 0) and
                       holds the arm there: still, for `calibrate` to read each joint's start
    release [JOINT]    the hand lets go of the joint (of every joint without one): it falls limp
    where              every joint's angle, its stops, and whether it is held, limp or under torque
    help               these lines

The hand is a torque from outside the arm (the plant's `external`): a critically damped spring of
time constant HAND_TIME_CONSTANT on the joint's own inertia that follows a minimum-jerk path to
the angle, carrying the arm's weight at that joint, so the joint stays where it was put and the
servo, limp, reads where the joint is (the truth is the plant's angle; what the servo reports
goes through the horn's mounting, which is what `calibrate` finds). The hand lets go of a joint
once its device's torque is on: the servo has it from then on. The plant must run for the hand
to move anything: `servodyn sim` without `--lockstep` runs it on the wall clock; in lock-step it
runs only with the host's ticks.
"""

from __future__ import annotations

import inspect
import math
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

from servodyn.errors import ServodynError

from .plant import STOP_TIME_CONSTANT

MOVE_TIME = 1.0                        # s: a `move` or a `push`, from where the joint is to where it goes
HAND_TIME_CONSTANT = STOP_TIME_CONSTANT    # s: the hand is as stiff as a stop
SETTLE = 0.1                           # s of plant time after a move before it is reported done
POLL = 0.02                            # s of wall clock between two looks at the plant's clock
STALLED = 3.0                          # s of wall clock with the plant's clock standing still: it is not running
HELP = __doc__.split("Commands", 1)[1].split("\n\n", 2)[1].rstrip()


class ConsoleError(ServodynError):
    """A console line that cannot be done (one line, said to the user; the console goes on)."""


@dataclass(frozen=True)
class _Path:
    """A minimum-jerk move of one joint from `start` at `t0` to `goal` over `duration` (rad, s)."""
    start: float
    goal: float
    t0: float
    duration: float

    def at(self, t: float) -> tuple[float, float, float]:
        """Angle, speed and acceleration of the path at plant time t (held at the goal after it)."""
        s = min(max((t - self.t0) / self.duration, 0.0), 1.0)
        span = self.goal - self.start
        return (self.start + span * (10 * s**3 - 15 * s**4 + 6 * s**5),
                span * (30 * s**2 - 60 * s**3 + 30 * s**4) / self.duration,
                span * (60 * s - 180 * s**2 + 120 * s**3) / self.duration**2)

    @property
    def end(self) -> float:
        return self.t0 + self.duration


class Hand:
    """The torque a hand puts on the joints it holds (the plant's `external`); its paths are set
    under the robot's lock, read by the plant's step."""

    def __init__(self, robot):
        self.robot, self.plant = robot, robot.plant
        self.paths: dict[int, _Path] = {}
        with robot.lock:
            # each joint's own inertia where the arm stands (mass_matrix must not run beside a step)
            self.inertia = np.diag(self.plant.model.mass_matrix(self.plant.q)).copy()
        self.rate = 1.0 / HAND_TIME_CONSTANT

    def __call__(self, t: float, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        tau = np.zeros_like(q)
        if not self.paths:
            return tau
        for k in [k for k in self.paths if self.robot.drives[k].torque_enabled]:
            del self.paths[k]                 # the servo has the joint now: the hand lets go
        if not self.paths:
            return tau
        weight = self.plant.model.inverse_dynamics(q, np.zeros_like(q), np.zeros_like(q))
        w = self.rate
        for k, path in self.paths.items():
            x, v, a = path.at(t)
            tau[k] = weight[k] + self.inertia[k] * (a + w * w * (x - q[k]) + 2.0 * w * (v - qd[k]))
        return tau


class Console:
    """The console's commands on one simulated robot (the module's docstring)."""

    def __init__(self, robot_or_server, *, move_time: float = MOVE_TIME, clock: Callable[[], float] = time.monotonic):
        robot = getattr(robot_or_server, "robot", robot_or_server)
        if not hasattr(robot, "plant") or not hasattr(robot, "lock"):
            raise ConsoleError("the console needs the simulated robot in this process (a simulator served by a "
                               "child process takes its console there)")
        self.robot, self.plant, self.move_time, self.clock = robot, robot.plant, move_time, clock
        self.dofs = list(robot.model.dof_names)
        with robot.lock:
            if isinstance(self.plant.external, Hand):
                self.hand = self.plant.external
            elif self.plant.external is None:
                self.hand = self.plant.external = Hand(robot)
            else:
                raise ConsoleError("something else already acts on this plant's joints")

    # --- one line ------------------------------------------------------------------------------

    def do(self, line: str) -> str:
        """The answer to one line ("" for an empty one); ConsoleError for a line that cannot be done."""
        words = line.split()
        if not words:
            return ""
        verb, args = words[0].lower(), words[1:]
        action = {"move": self.move, "push": self.push, "zero": self.zero, "release": self.release, "where": self.where,
                  "help": lambda: HELP}.get(verb)
        if action is None:
            raise ConsoleError(f"no command '{verb}': move JOINT DEG, push JOINT +|-, zero, release [JOINT], where, help")
        try:
            inspect.signature(action).bind(*args)
        except TypeError:
            raise ConsoleError(f"'{verb}' takes: {self._usage(verb)}") from None
        return action(*args)

    @staticmethod
    def _usage(verb: str) -> str:
        return next(line.split("  ")[0].strip() for line in HELP.splitlines() if line.strip().startswith(verb))

    def joint(self, name: str) -> int:
        """The dof a name means: its own name, or the one dof name that holds it."""
        if name in self.dofs:
            return self.dofs.index(name)
        matches = [k for k, dof in enumerate(self.dofs) if name.lower() in dof.lower()]
        if len(matches) == 1:
            return matches[0]
        if matches:
            raise ConsoleError(f"'{name}' names {len(matches)} joints: {', '.join(self.dofs[k] for k in matches)}")
        raise ConsoleError(f"no joint '{name}' (joints: {', '.join(self.dofs)})")

    def move(self, joint: str, degrees: str) -> str:
        k = self.joint(joint)
        try:
            goal = math.radians(float(degrees))
        except ValueError:
            raise ConsoleError(f"'{degrees}' is not an angle in degrees") from None
        lower, upper = self.plant.lower[k], self.plant.upper[k]
        if not math.isfinite(goal) or not lower <= goal <= upper:
            side = "-" if goal < lower else "+"
            raise ConsoleError(f"{self.dofs[k]} stops at {math.degrees(lower):.1f}° and {math.degrees(upper):.1f}°: "
                               f"{degrees}° is past its {side} stop (`push {self.dofs[k]} {side}` puts it there)"
                               if math.isfinite(goal) else f"'{degrees}' is not an angle in degrees")
        return self._take(k, goal)

    def push(self, joint: str, side: str) -> str:
        k = self.joint(joint)
        if side not in ("+", "-"):
            raise ConsoleError(f"push {self.dofs[k]} + or push {self.dofs[k]} - (its + or - stop), not '{side}'")
        return self._take(k, self.plant.upper[k] if side == "+" else self.plant.lower[k], f"on its {side} stop")

    def zero(self) -> str:
        with self.robot.lock:
            limp = [k for k, drive in enumerate(self.robot.drives) if not drive.torque_enabled]
        if not limp:
            raise ConsoleError("every servo has torque on: nothing for the hand to move")
        answers = self._take(limp, [0.0] * len(limp))
        return answers

    def release(self, joint: str | None = None) -> str:
        with self.robot.lock:
            held = sorted(self.hand.paths) if joint is None else [self.joint(joint)]
            for k in held:
                self.hand.paths.pop(k, None)
        return "let go of " + (", ".join(self.dofs[k] for k in held) if held else "nothing (no joint held)")

    def where(self) -> str:
        with self.robot.lock:
            q = self.plant.q.copy()
            held = set(self.hand.paths)
            torque = [d.torque_enabled for d in self.robot.drives]
        width = max(map(len, self.dofs))
        rows = [f"{'joint':<{width}}  {'angle':>8}  {'stops':>16}  hand"]
        for k, dof in enumerate(self.dofs):
            state = "torque on" if torque[k] else "held" if k in held else "limp"
            stops = f"{math.degrees(self.plant.lower[k]):.0f}° .. {math.degrees(self.plant.upper[k]):.0f}°"
            rows.append(f"{dof:<{width}}  {math.degrees(q[k]):7.2f}°  {stops:>16}  {state}")
        return "\n".join(rows) + f"\n(plant time {self.plant.time:.2f} s)"

    # --- the hand's move -------------------------------------------------------------------------

    def _take(self, joints: int | list[int], goals: float | list[float], where: str = "") -> str:
        """Hold the joints and take each to its goal over the move time; the answer once they are
        there (or why not)."""
        joints, goals = ([joints], [goals]) if isinstance(joints, int) else (joints, goals)
        with self.robot.lock:
            for k in joints:
                if self.robot.drives[k].torque_enabled:
                    raise ConsoleError(f"{self.dofs[k]}'s servo has torque on: it holds the joint, not the hand "
                                       "(`servodyn torque off` first)")
            paths = {k: _Path(float(self.plant.q[k]), float(goal), self.plant.time, self.move_time)
                     for k, goal in zip(joints, goals)}
            self.hand.paths.update(paths)
        end = max(path.end for path in paths.values()) + SETTLE
        named = self.dofs[joints[0]] if len(joints) == 1 else f"{len(joints)} joints"
        last, still_since = self.plant.time, self.clock()
        while True:
            with self.robot.lock:
                now, q = self.plant.time, self.plant.q.copy()
                let_go = [k for k, path in paths.items() if self.hand.paths.get(k) is not path]
            if let_go:
                return (f"{', '.join(self.dofs[k] for k in let_go)}: the hand let go at "
                        f"{', '.join(f'{math.degrees(q[k]):.1f}°' for k in let_go)} (its servo took it, or another move)")
            if now >= end:
                angles = ", ".join(f"{math.degrees(q[k]):.1f}°" for k in joints) if len(joints) == 1 else \
                    f"their zero (within {max(abs(math.degrees(q[k])) for k in joints):.2f}°)"
                return f"{named} at {angles}{' ' + where if where else ''} (held)"
            if now != last:
                last, still_since = now, self.clock()
            elif self.clock() - still_since > STALLED:
                return (f"{named}: the hand holds it and moves it as the plant runs; the plant's clock has stood "
                        f"still for {STALLED:g} s (lock-step runs with the host's ticks)")
            time.sleep(POLL)


def run_console(robot_or_server, lines_in: Iterable[str], say: Callable = print) -> None:
    """Each line of `lines_in` (a terminal's standard input) done on the robot and its answer said,
    a line that cannot be done said in one line, until the input ends. For a thread of its own
    beside the simulator's serving loop: it takes the robot's lock only between two packets."""
    try:
        console = Console(robot_or_server)
    except ConsoleError as err:
        say(f"console: {err}")
        return
    say("console: move JOINT DEG, push JOINT +|-, zero, release [JOINT], where, help")
    for line in lines_in:
        try:
            answer = console.do(line)
        except ConsoleError as err:
            answer = f"error: {err}"
        if answer:
            say(answer)


def start_console(robot_or_server, lines_in: Iterable[str], say: Callable = print) -> threading.Thread:
    """run_console in a daemon thread (it ends with the process, or when the input ends)."""
    thread = threading.Thread(target=run_console, args=(robot_or_server, lines_in, say), name="sim console",
                              daemon=True)
    thread.start()
    return thread
