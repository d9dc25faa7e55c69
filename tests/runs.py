"""A run of a configuration as the tests start one: servodyn.report.swing.play with the run's
options as keywords (servodyn.loop.run.RunOptions), quiet unless `say` is given."""

from pathlib import Path

from servodyn.loop.run import RunOptions
from servodyn.report.swing import play


def run_swing(config="replica", out=Path("out/swing"), *, say=lambda *a, **k: None, confirm=None, observer=None,
              log=None, figure=True, **options) -> dict:
    return play(config, RunOptions(**options), Path(out), say=say, confirm=confirm, observer=observer, log=log,
                figure=figure)
