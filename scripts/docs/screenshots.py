"""The view's pictures in the documents (docs/view/*.png), taken from the page the browser tests
drive: headless Chromium with software WebGL (tests/browser.py), the replica shaping the forehand
and a logged run replayed (the lock-step swing under the PD alone, so the ghost, the plan, stands
apart from the measured arm).

    python scripts/docs/screenshots.py [DIR]      # default docs/view; `make docs` runs it

Pictures are not checked (their pixels vary with the browser's build); `make docs` rewrites them.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))

import browser  # noqa: E402   (tests/browser.py: the DevTools client of the browser tests)


# the browser's own notice about software WebGL, closed before a picture is taken
CLOSE_NOTICES = "document.querySelectorAll('.mantine-Notification-closeButton').forEach(b => b.click())"
CASES = (("view_shape.png", {}, None), ("view_replay.png", {"log": "out/swing"}, 5.0))   # (file, view, time)


def take(out: Path) -> list[Path]:
    """Each picture: the page opened, loaded, its notices closed, once it has stopped drawing.
    In the current folder, where out/swing holds the run replayed."""
    from PIL import Image
    from servodyn.tools.view import open_view
    out.mkdir(parents=True, exist_ok=True)
    written = []
    with browser.Browser() as page:
        for name, options, t in CASES:
            viewer = open_view("replica", port=0, say=lambda *a, **k: None, **options)
            try:
                if viewer.editor is not None:
                    viewer.editor.key.value = 7            # keyframe 7: contact
                else:
                    viewer.seek(t)
                page.open(viewer.url)
                browser.wait_for(lambda: "loaded" in page.text(), "the page")
                time.sleep(2.0)
                page.eval(CLOSE_NOTICES)
                Image.fromarray(browser.settle(page).astype(np.uint8)).save(out / name)
                written.append(out / name)
            finally:
                viewer.close()
    return written


def main(argv: list[str]) -> int:
    out = (Path(argv[0]) if argv else ROOT / "docs" / "view").resolve()
    here = os.getcwd()
    with tempfile.TemporaryDirectory(prefix="servodyn-shots-") as scratch:
        os.chdir(scratch)                  # the replayed run is shown as out/swing, as the README's command makes it
        try:
            swing = subprocess.run([sys.executable, "-m", "servodyn.tools.cli", "swing", "--no-feedforward",
                                    "--out", "out/swing"], capture_output=True, text=True)
            if swing.returncode != 0:
                print(f"screenshots: the swing to replay failed (exit {swing.returncode}): "
                      f"{(swing.stderr.strip().splitlines() or ['no output'])[-1]}", file=sys.stderr)
                return 1
            written = take(out)
        finally:
            os.chdir(here)
    for path in written:
        print(f"wrote {path.relative_to(ROOT) if path.is_relative_to(ROOT) else path}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
