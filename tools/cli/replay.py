"""`servodyn replay LOG.json... --servo MODEL`: servo-bench logs replayed through the servo model."""

from __future__ import annotations

from ..replay import run as run_replay
from .common import describe, say


def add_arguments(p) -> None:
    describe(p, "Replays servo-bench logs (JSON: a servo in its own position mode swinging a pendulum; "
             "docs/servo-bench.md) through the simulated servo and pendulum: from the first logged position and "
             "speed, the servo's position law runs on the simulated position from the logged goals, P gain, "
             "supply and temperature. Writes one CSV per log (t,q_measured,q_predicted and, where the log has "
             "the Present PWM, duty_measured,duty_predicted; one row per log entry), DIR/replay.json and "
             "DIR/replay.png; prints the mean absolute position error per log and over the logs.",
             "servodyn replay bench/run1.json --servo XL330-M288 -o out/run1.csv",
             "servodyn replay bench/*.json --servo XL330-M288 --actuator out/identify/actuator.json --out out/replay",
             exits="0 done")
    p.add_argument("logs", nargs="+", metavar="LOG.json", help="servo-bench logs")
    p.add_argument("--servo", required=True, metavar="MODEL",
                   help="the catalogue servo (servodyn list), Dynamixel or Feetech, e.g. XL330-M288 or STS3250")
    p.add_argument("--actuator", default=None, metavar="FILE",
                   help="actuator.json from `servodyn identify --actuator` (default: the catalogue's motor)")
    p.add_argument("-o", "--output", default=None, metavar="OUT.csv", help="one log's CSV here (one LOG only)")
    p.add_argument("--out", default="out/replay", metavar="DIR",
                   help="folder for the figure, replay.json and (without -o) each log's CSV (default out/replay)")


def run(args) -> int:
    return run_replay(args.logs, args.servo, args.actuator, args.output, args.out, say)
