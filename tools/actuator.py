"""`servodyn identify --actuator MODEL LOG.json...`: a servo's motor from servo-bench logs
(identification.actuator), written as DIR/actuator.json in the catalogue's units, with a table of
the parameters, their standard errors and what the logs could not tell, and the replay's error."""

from __future__ import annotations

import json
import time
from pathlib import Path

from ..identification.actuator import FITTED, identify_actuator
from ..identification.bench_servo import bench_servo


def run(servo_name: str, paths, out: Path, say) -> int:
    servo = bench_servo(servo_name)
    logs = [servo.read(p) for p in paths]
    start = time.process_time()
    fit = identify_actuator(logs, servo)
    seconds = time.process_time() - start
    out.mkdir(parents=True, exist_ok=True)
    data = fit.as_json()
    data["logs"] = [log.path for log in logs]
    data["position_law"] = {"duty_per_p_rad": servo.gain_per_p, "law": servo.law}
    file = out / "actuator.json"
    file.write_text(json.dumps(data, indent=2) + "\n")
    print(f"{'parameter':<26} {'value':>11} {'std':>10}  unit")
    for key, _, unit in FITTED:
        p = fit.parameters[key]
        std = "-" if p.std is None else f"{p.std:.3g}"
        mark = "" if p.determined else "  not determined"
        value = f"{data[key]:.5g}" if key in data else "-"
        print(f"{key:<26} {value:>11} {std:>10}  {unit}{mark}")
    for key, why in data["assumed"].items():
        print(f"undetermined: {key}: {why}")
    print(f"replay mean |q error| over {len(logs)} logs: {data['replay_error_rad']['mean']:.4f} rad "
          f"({fit.evaluations} rollouts, {seconds:.2f} s of CPU)")
    say(f"wrote {file}; use it with: servodyn replay LOG.json --servo {servo.name} --actuator {file}")
    return 0
