"""Headless Chromium driven through the Chrome DevTools protocol: the browser tests of `servodyn
view` and the README's screenshots of it.

Debian's `chromium` (scripts/install/install-browser.sh installs it when missing) runs headless
with software WebGL (SwiftShader); the protocol's websocket is spoken with `websockets`, which viser
itself depends on. Every wait polls for its condition with a deadline: nothing here depends on how
fast the machine is.

    python tests/browser.py --screenshots DIR     the README's pictures of the page
"""

from __future__ import annotations

import argparse
import base64
import io
import itertools
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import numpy as np

from servodyn.tools.view import open_view

from helpers import quiet, wait_until

ROOT = Path(__file__).resolve().parents[1]
SCREEN = (1200, 800)
DEADLINE = 60.0          # s for any one condition to hold on a busy machine


def find_chromium(install: bool = True) -> str:
    for name in ("chromium", "chromium-browser"):
        if shutil.which(name):
            return shutil.which(name)
    script = ROOT / "scripts/install/install-browser.sh"
    if install and script.exists():
        res = subprocess.run([str(script)], capture_output=True, text=True)
        if res.returncode == 0 and shutil.which("chromium"):
            return shutil.which("chromium")
        raise RuntimeError(f"chromium could not be installed: {(res.stdout + res.stderr).strip()}")
    raise RuntimeError("chromium is not installed (Debian: apt-get install chromium)")


def wait_for(condition, what: str, deadline: float = DEADLINE, every: float = 0.25):
    """condition()'s first true value (wait_until's); AssertionError naming `what` after
    `deadline` seconds."""
    value = wait_until(condition, deadline, every)
    if not value:
        raise AssertionError(f"waited {deadline:g} s for {what}")
    return value


class Browser:
    """One headless chromium and its first page, driven one protocol call at a time."""

    def __init__(self, size=SCREEN):
        self.size = size
        # chromium's helper processes may still be writing its profile after the main one
        # exits: the whole session is stopped at close(), and a file they left is no error
        self.profile = tempfile.TemporaryDirectory(prefix="servodyn-chromium-", ignore_cleanup_errors=True)
        self.proc = subprocess.Popen(
            [find_chromium(), "--headless=new", "--no-sandbox", "--use-angle=swiftshader",
             "--enable-unsafe-swiftshader", f"--window-size={size[0]},{size[1]}", "--remote-debugging-port=0",
             f"--user-data-dir={self.profile.name}", "--no-first-run", "--hide-scrollbars", "about:blank"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        self.ws = None
        try:
            port_file = Path(self.profile.name) / "DevToolsActivePort"
            wait_for(lambda: port_file.exists() and port_file.read_text().strip(), "chromium's DevTools port")
            port = int(port_file.read_text().split()[0])
            from websockets.sync.client import connect
            targets = json.load(urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=DEADLINE))
            page = next(t for t in targets if t["type"] == "page")
            self.ws = connect(page["webSocketDebuggerUrl"], max_size=None, open_timeout=DEADLINE)
            self.ids = itertools.count(1)
            self.call("Page.enable")
            self.call("Emulation.setDeviceMetricsOverride", width=size[0], height=size[1], deviceScaleFactor=1,
                      mobile=False)
        except BaseException:
            self.close()
            raise

    def call(self, method: str, **params):
        i = next(self.ids)
        self.ws.send(json.dumps({"id": i, "method": method, "params": params}))
        while True:
            message = json.loads(self.ws.recv(timeout=DEADLINE))
            if message.get("id") == i:
                if "error" in message:
                    raise RuntimeError(f"{method}: {message['error']}")
                return message["result"]

    def open(self, url: str) -> None:
        self.call("Page.navigate", url=url)

    def eval(self, expression: str):
        return self.call("Runtime.evaluate", expression=expression, returnByValue=True)["result"].get("value")

    def text(self) -> str:
        return self.eval("document.body ? document.body.innerText : ''") or ""

    def screenshot(self) -> np.ndarray:
        """The page as (height, width, 3) RGB integers."""
        from PIL import Image
        data = self.call("Page.captureScreenshot", format="png")["data"]
        return np.asarray(Image.open(io.BytesIO(base64.b64decode(data))).convert("RGB")).astype(int)

    def type_into(self, label: str, text: str) -> bool:
        """Focus the input labelled `label`, select its text, type `text` and press Enter, as a
        person would; False if no such input."""
        found = self.eval(f"""(() => {{
            const label = [...document.querySelectorAll('label')].find(l => l.innerText.trim() === {json.dumps(label)});
            const input = label && document.getElementById(label.htmlFor);
            if (!input) return false;
            input.scrollIntoView(); input.focus(); input.select();
            return document.activeElement === input;
        }})()""")
        if not found:
            return False
        self.call("Input.insertText", text=text)
        for kind in ("keyDown", "keyUp"):
            self.call("Input.dispatchKeyEvent", type=kind, key="Enter", code="Enter", windowsVirtualKeyCode=13)
        self.eval("document.activeElement && document.activeElement.blur()")
        return True

    def close(self) -> None:
        if self.ws is not None:
            self.ws.close()
        self._signal_session(signal.SIGTERM)
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self._signal_session(signal.SIGKILL)     # any helper process the main one left behind
        self.profile.cleanup()

    def _signal_session(self, signum) -> None:
        try:
            os.killpg(self.proc.pid, signum)
        except ProcessLookupError:
            pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def settle(browser: Browser, rounds: int = 2, deadline: float = DEADLINE) -> np.ndarray:
    """A screenshot once `rounds` in a row came out the same (the scene has finished drawing)."""
    last, same = None, 0
    end = time.monotonic() + deadline
    while time.monotonic() < end:
        shot = browser.screenshot()
        same = same + 1 if last is not None and np.array_equal(shot, last) else 0
        if same >= rounds - 1:
            return shot
        last = shot
        time.sleep(0.5)
    return last


def screenshots(out: Path, log: Path | None) -> list[Path]:
    """The README's pictures: shaping the forehand on the replica, and a logged run replayed."""
    from PIL import Image
    out.mkdir(parents=True, exist_ok=True)
    written = []
    cases = [("view_shape.png", dict(), 0.0)]
    if log is not None:
        cases.append(("view_replay.png", dict(log=str(log)), 5.0))
    with Browser() as browser:
        for name, options, t in cases:
            viewer = open_view("replica", port=0, **options, say=quiet)
            try:
                if viewer.editor is not None:
                    viewer.editor.key.value = 7          # the end of the backswing
                else:
                    viewer.seek(t)
                browser.open(viewer.url)
                wait_for(lambda: "loaded" in browser.text(), "the page")
                time.sleep(2.0)
                Image.fromarray(settle(browser).astype(np.uint8)).save(out / name)
                written.append(out / name)
            finally:
                viewer.close()
    return written


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python tests/browser.py", description=__doc__.splitlines()[0])
    parser.add_argument("--screenshots", required=True, metavar="DIR", help="write the README's screenshots here")
    parser.add_argument("--log", default=None, metavar="DIR", help="a run's folder to show replayed")
    args = parser.parse_args(argv)
    for path in screenshots(Path(args.screenshots), Path(args.log) if args.log else None):
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
