"""`servodyn replay`: servo-bench logs (JSON, docs/servo-bench.md) replayed through the simulated
servo and its pendulum (identification.bench.rollout): from the first logged position and speed, the
servo's own position law runs on the simulated position from the logged goals, gain, supply and
temperature. Per log a CSV, one row per log entry (t, q_measured, q_predicted and, where the log has
the Present PWM, duty_measured, duty_predicted), the mean absolute position error per log and over
the logs, and a figure of both."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..identification.actuator import law_duty, load_actuator, pwm_read_lag
from ..identification.bench import Grid, rollout
from ..identification.bench_servo import bench_servo
from ..report.plots import _pyplot, short

SATURATED = 0.95       # |duty| at or above: the law saturated, its duty is left out of the duty error


@dataclass(frozen=True)
class Replayed:
    """One log's replay: its samples, the predicted position and duty, and the scores."""
    log: object
    pwm_full: float              # the log's PWM units at 100 % duty
    q_predicted: np.ndarray
    duty_predicted: np.ndarray
    error: float                 # mean |q_predicted − q_measured|, rad
    duty_error: float | None     # mean |duty_predicted − duty_measured| on unsaturated samples (None: no PWM)

    @property
    def duty_measured(self) -> np.ndarray | None:
        return None if self.log.pwm is None else self.log.pwm / self.pwm_full

    def rows(self) -> tuple[list[str], np.ndarray]:
        cols = {"t": self.log.t, "q_measured": self.log.q, "q_predicted": self.q_predicted}
        if self.log.pwm is not None:
            cols.update(duty_measured=self.duty_measured, duty_predicted=self.duty_predicted)
        return list(cols), np.column_stack(list(cols.values()))


def replay(paths, servo_name: str, actuator=None) -> tuple[list[Replayed], float]:
    """Every log replayed at once; and the lag (s) at which the logs' Present PWM was read (compared there)."""
    servo = bench_servo(servo_name)
    logs = [servo.read(p) for p in paths]
    motor, offset = load_actuator(actuator, servo.motor) if actuator else (servo.motor, 0.0)
    gains = [servo.duty_per_rad(log.kp) for log in logs]
    lag = pwm_read_lag(logs, gains, servo.pwm_full)
    grid = Grid.of(logs)
    qs = rollout(grid, motor, np.array(gains), offset)[0]
    out = []
    for j, log in enumerate(logs):
        q = grid.sample(qs, j)[:, 0]
        # the law on the predicted position where the PWM was read, with the goal the log holds then (a
        # goal written every 20 ms moves the law by a tenth of full duty between two steps: interpolating
        # the rollout's duty across that jump would blur it)
        duty = law_duty(log, gains[j], grid.sample(qs, j, lag)[:, 0], motor.max_duty) * log.enabled
        duty_error = None
        if log.pwm is not None:
            measured = log.pwm / servo.pwm_full
            fair = log.enabled & (np.abs(measured) < SATURATED) & (np.abs(duty) < SATURATED)
            duty_error = float(np.mean(np.abs(duty - measured)[fair])) if fair.any() else None
        out.append(Replayed(log, servo.pwm_full, q, duty, float(np.mean(np.abs(q - log.q))), duty_error))
    return out, lag


def figure(path: Path, replayed: list[Replayed], title: str) -> None:
    """Per log, the measured and predicted position (and duty where logged)."""
    plt = _pyplot()
    n = len(replayed)
    fig, axes = plt.subplots(n, 2, figsize=(11, 2.2 * n + 0.6), squeeze=False, sharex="col")
    for (ax_q, ax_d), r in zip(axes, replayed):
        ax_q.plot(r.log.t, r.log.q, "k", lw=1.2, label="measured")
        ax_q.plot(r.log.t, r.q_predicted, "C1", lw=1.0, label="predicted")
        ax_q.plot(r.log.t, r.log.goal, "0.6", lw=0.8, ls=":", label="goal")
        ax_q.set_ylabel("q (rad)")
        ax_q.set_title(short(f"{r.log.name} kp {r.log.kp:g} {r.log.trajectory}: {r.error:.4f} rad", 60), fontsize=9)
        if r.duty_measured is not None:
            ax_d.plot(r.log.t, r.duty_measured, "k", lw=1.0, label="measured")
            ax_d.plot(r.log.t, r.duty_predicted, "C1", lw=0.8, label="predicted")
            ax_d.set_title(f"duty error {r.duty_error:.4f} (unsaturated)", fontsize=9)
        ax_d.set_ylabel("duty")
        for ax in (ax_q, ax_d):
            ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7)
    axes[-1, 0].set_xlabel("time (s)")
    axes[-1, 1].set_xlabel("time (s)")
    fig.suptitle(short(title, 110), fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.98))
    fig.savefig(path, dpi=90)
    plt.close(fig)


def write_csv(path: Path, r: Replayed) -> None:
    header, data = r.rows()
    np.savetxt(path, data, delimiter=",", header=",".join(header), comments="", fmt="%.7g")


def run(paths, servo_name: str, actuator, output, out, say) -> int:
    if output is not None and len(paths) != 1:
        raise InputError(f"-o writes one log's CSV, and {len(paths)} logs were given: use --out DIR")
    replayed, lag = replay(paths, servo_name, actuator)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if output is not None:
        Path(output).parent.mkdir(parents=True, exist_ok=True)
        write_csv(Path(output), replayed[0])
    else:
        for r in replayed:
            write_csv(out / f"{r.log.name}.csv", r)
    mean = float(np.mean([r.error for r in replayed]))
    duty = [r.duty_error for r in replayed if r.duty_error is not None]
    print(f"{'log':<24} {'kp':>5} {'trajectory':<16} {'|q err| rad':>11} {'|duty err|':>10}")
    for r in replayed:
        d = "-" if r.duty_error is None else f"{r.duty_error:.4f}"
        print(f"{r.log.name:<24} {r.log.kp:>5g} {r.log.trajectory:<16} {r.error:>11.4f} {d:>10}")
    print(f"{'mean':<47} {mean:>11.4f} {np.mean(duty) if duty else float('nan'):>10.4f}")
    source = f"--actuator {actuator}" if actuator else f"the catalogue's {servo_name}"
    summary = {"servo": servo_name, "motor": source, "pwm_read_lag_s": lag, "mean_error_rad": mean,
               "mean_duty_error": float(np.mean(duty)) if duty else None,
               "logs": [{"log": r.log.path, "kp": r.log.kp, "trajectory": r.log.trajectory, "error_rad": r.error,
                         "duty_error": r.duty_error} for r in replayed]}
    (out / "replay.json").write_text(json.dumps(summary, indent=2) + "\n")
    figure(out / "replay.png", replayed, f"replay of {len(replayed)} log(s) on {servo_name} ({source}): "
                                         f"mean {mean:.4f} rad")
    say(f"wrote {output or out} (CSV), {out / 'replay.png'}, {out / 'replay.json'}; Present PWM compared "
        f"{lag * 1e3:.1f} ms after the position (the logs' read order)")
    return 0
