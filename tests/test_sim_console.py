"""The console's hand on the simulated bench (sim/console.py): `servodyn calibrate`'s by-hand steps
done through it on the factory bench find each horn's mounting, as a person at a real arm would.

The simulator runs in this process on the wall clock (as `servodyn sim` serves it); `setup` and
`calibrate` are the commands a user types, each in its own process against the pseudo-terminal."""

from __future__ import annotations

import math
import os
import random
import select
import subprocess
import sys
import threading
import time

import pytest
import tomlkit

from servodyn.hal.config import load_config
from servodyn.hal.dynamixel.control_table import ITEMS
from servodyn.sim.console import Console, ConsoleError, run_console
from servodyn.sim.lab import Lab
from servodyn.sim.robot import SimulatedRobot
from servodyn.sim.serve import serve

CONFIG = load_config("replica")
DOFS = list(CONFIG.model.dof_names)
TICK = 2 * math.pi / 4096          # rad: one tick of a Dynamixel X's position
JOINT = "r_elbow_flexion"


def seed_turning(dof: str, turned: bool) -> int:
    """A bench seed whose factory mounting reverses `dof` (turned) or leaves its direction (sim/lab.py's
    factory_mounting draws the reversed joint first)."""
    k = DOFS.index(dof)
    return next(s for s in range(100) if (random.Random(s).randrange(len(DOFS)) == k) == turned)


def cli(*argv, timeout=120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "servodyn.tools.cli", *argv], capture_output=True, text=True,
                          timeout=timeout, stdin=subprocess.DEVNULL)


def answer_prompts(proc: subprocess.Popen, act, deadline: float = 120.0) -> str:
    """Everything the command printed; at each "[Enter] " prompt `act(prompt)` is done first, at a
    "[y/N] " question the answer is y."""
    text, line = "", ""
    end = time.monotonic() + deadline
    fd = proc.stdout.fileno()
    while time.monotonic() < end:
        ready, _, _ = select.select([fd], [], [], 0.5)
        if not ready:
            if proc.poll() is not None:
                break
            continue
        chunk = os.read(fd, 4096).decode()
        if not chunk:
            break
        text += chunk
        line = (line + chunk).rsplit("\n", 1)[-1]
        if line.endswith("[Enter] "):
            act(line)
            proc.stdin.write(b"\n")
            proc.stdin.flush()
            line = ""
        elif line.endswith("[y/N] "):
            proc.stdin.write(b"y\n")
            proc.stdin.flush()
            line = ""
    return text


@pytest.mark.timeout(300)
@pytest.mark.parametrize("reversed_horn", [False, True], ids=["as-configured-direction", "reversed-horn"])
def test_calibrate_by_hand_through_the_console_finds_the_mounting(tmp_path, reversed_horn):
    store, target = tmp_path / "bench.json", tmp_path / "replica.toml"
    bench = Lab(factory=True, connected=(JOINT,), store=store, seed=seed_turning(JOINT, reversed_horn))
    served = serve(CONFIG, "realtime", process=False, lab=bench)
    try:
        port = served.buses["arm"]["port"]
        truth = served.robot.bench.mounting[JOINT]
        configured = next(j for j in CONFIG.joints if j.dof == JOINT)
        assert (truth.direction != configured.direction) == reversed_horn     # the bench this case wants
        setup = cli("setup", "--config", "replica", "--joint", JOINT, "--port", port, "--yes")
        assert setup.returncode == 0, setup.stdout + setup.stderr
        console = Console(served)
        assert "held" in console.do("zero")            # the arm still, so calibrate reads a steady start
        # what a person does at each of calibrate's prompts, in the console's words
        steps = iter([["move elbow 20"], ["push elbow -"], ["move elbow 10", "move elbow 0"], ["push elbow -"],
                      ["push elbow +"]])
        said = []
        proc = subprocess.Popen([sys.executable, "-m", "servodyn.tools.cli", "calibrate", "--config", "replica",
                                 "--port", port, "--joint", JOINT, "--margin", "0", "--write", str(target)],
                                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
        try:
            text = answer_prompts(proc, lambda prompt: said.extend(console.do(line) for line in next(steps)))
            code = proc.wait(timeout=30)
        finally:
            proc.kill()
        assert code == 0, text + "\n".join(said)
    finally:
        served.stop()
    joint = next(j for j in tomlkit.parse(target.read_text())["joint"] if j["dof"] == JOINT)
    assert joint["direction"] == truth.direction, text
    # the hand holds the joint within hundredths of a degree; the servo reads it to a tick
    assert joint["zero_offset"] == pytest.approx(truth.zero_offset, abs=TICK), text
    # the stops are the model's limits (the plant's), read to a tick; margin 0
    lower, upper = CONFIG.model.lower[DOFS.index(JOINT)], CONFIG.model.upper[DOFS.index(JOINT)]
    assert list(joint["position_limits"]) == pytest.approx([lower, upper], abs=TICK), text


def test_a_bad_line_is_one_line_and_the_console_goes_on():
    robot = SimulatedRobot(CONFIG)
    said = []
    run_console(robot, ["help", "jump elbow", "move elbow 200", "move shoulder 10", "move wrist_flex many",
                        "push elbow up", "move elbow", "release", "where"], said.append)
    errors = [s for s in said if s.startswith("error:")]
    # six refusals, each one line naming what was wrong, and the lines after them still done
    assert len(errors) == 6 and all("\n" not in e for e in errors), said
    assert "past its + stop" in errors[1] and "names 3 joints" in errors[2], errors
    assert said[-1].splitlines()[0].split() == ["joint", "angle", "stops", "hand"]
    assert len(said[-1].splitlines()) == len(DOFS) + 2, said[-1]


def test_the_hand_holds_a_joint_then_lets_go_once_its_servo_has_torque():
    robot = SimulatedRobot(CONFIG)
    k = DOFS.index(JOINT)
    running = threading.Event()
    running.set()

    def plant():                          # the wall clock's plant, as `servodyn sim` runs it
        while running.is_set():
            with robot.lock:
                robot.advance(0.02)
            time.sleep(0.002)
    thread = threading.Thread(target=plant, daemon=True)
    thread.start()
    try:
        console = Console(robot, move_time=0.3)
        assert console.do("move elbow 30").startswith(f"{JOINT} at 30.0°")
        time.sleep(0.3)
        # held against the forearm's weight: within a hundredth of a degree (gravity carried by the hand)
        assert math.degrees(robot.q[k]) == pytest.approx(30.0, abs=0.01)
        servo = robot.drives[k]
        with robot.lock:
            servo.write(ITEMS["torque_enable"].address, bytes([1]))
            robot.advance(0.01)
        assert k not in console.hand.paths                   # the servo has the joint now
        with pytest.raises(ConsoleError, match="torque on"):
            console.do("move elbow 40")
    finally:
        running.clear()
        thread.join(5)
