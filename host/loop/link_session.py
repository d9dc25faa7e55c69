"""The host's side of a controller on the host link (docs/host-link.md): requests through the
retransmitting Sender (servodyn.hal.link.sender), the controller's telemetry kept, a robot loaded
and a motion streamed within the controller's credits.

The line is a file descriptor: a pseudo-terminal's master (the native controller's link=PATH), a
socket, or a serial port.
"""

from __future__ import annotations

import os
import select
import time

from ..errors import InputError
from ..hal.link import messages as ms
from ..hal.link.sender import Sender
from .link_load import LinkPlan


SLOW_COMMAND = 3.0        # s a command that sets the bus up (HOME) may take before the controller is taken for gone


class ControllerRefused(InputError):
    """The controller refused a request (a robot its checks refuse, a command its state refuses)."""


class LinkSession:
    """A controller on `fd`. pump() moves bytes both ways and runs the retransmissions; telemetry
    frames land in `telemetry` (every one received, in order)."""

    def __init__(self, fd: int, clock=time.monotonic):
        self.fd, self.clock = fd, clock
        self.sender = Sender(self._write, clock)
        self.telemetry: list = []
        self.streamed = 0                 # knots sent so far
        self.bytes_in = self.bytes_out = 0
        self._knot_requests: list = []

    def _write(self, data: bytes) -> None:
        self.bytes_out += len(data)
        view = memoryview(data)
        while view:
            try:
                n = os.write(self.fd, view)
            except BlockingIOError:
                select.select([], [self.fd], [], 0.05)
                continue
            view = view[n:]

    def pump(self, wait: float = 0.0) -> None:
        ready, _, _ = select.select([self.fd], [], [], wait)
        while ready:
            try:
                data = os.read(self.fd, 65536)
            except (BlockingIOError, OSError):
                break
            if not data:
                break
            self.bytes_in += len(data)
            self.telemetry.extend(m for m in self.sender.receive(data) if isinstance(m, ms.Telemetry))
            ready, _, _ = select.select([self.fd], [], [], 0)
        self.sender.poll()

    @property
    def last(self):
        """The latest telemetry (None before any)."""
        return self.telemetry[-1] if self.telemetry else None

    def request(self, message, timeout: float = 5.0):
        """Send one request and wait for its answer (a Result or a HelloReply)."""
        req = self.sender.send(message)
        return self.wait(req, timeout)

    def wait(self, req, timeout: float = 5.0):
        deadline = self.clock() + timeout
        while req.answer is None:
            if self.clock() > deadline:
                raise TimeoutError(f"host link: no answer to {type(req.message).__name__} within {timeout:g} s")
            self.pump(0.002)
        return req.answer

    def hello(self, nonce: int = 0x5D5D) -> object:
        return self.request(ms.Hello(nonce=nonce))

    def load(self, messages) -> object:
        """Load a robot (messages: LOAD_ROBOT, bodies, joints) and COMMIT it; the COMMIT's Result.
        ControllerRefused, with the controller's reason, when a message or the check refuses it."""
        requests = [self.sender.send(m) for m in [*messages, ms.Commit()]]
        for req in requests:
            result = self.wait(req)
            if result.code != 0:
                raise ControllerRefused(f"the controller refused the robot: {ms.reason(result)}")
        return requests[-1].answer

    def command(self, name: str, arg: int = 0, check: bool = True):
        """One command, answered. HOME sets the bus up before it answers (every servo written and
        read, each within the controller's reply timeout): the host waits up to SLOW_COMMAND for it,
        retransmitting at the same pace, where a lost answer would otherwise end the session."""
        if name == "home":
            timeout = self.sender.timeout
            self.sender.timeout = max(timeout, SLOW_COMMAND / self.sender.retries)
            try:
                # the sender gives up after its retries; this wait outlasts them
                result = self.request(ms.Command(command=ms.COMMANDS[name], arg=arg),
                                      timeout=self.sender.timeout * (self.sender.retries + 1) + 1)
            finally:
                self.sender.timeout = timeout
        else:
            result = self.request(ms.Command(command=ms.COMMANDS[name], arg=arg))
        if check and result.code != 0:
            raise ControllerRefused(f"the controller refused {name}: {ms.reason(result)}")
        return result

    def stream(self, plan: LinkPlan) -> int:
        """Send the motion's next knots, as many as the controller's credits allow now; the knots
        sent so far."""
        for req in [r for r in self._knot_requests if r.answer is not None]:
            self._knot_requests.remove(req)
            if req.answer.code != 0:
                raise ControllerRefused(f"the controller refused knots from {req.message.first}: "
                                        f"{ms.reason(req.answer)}")
        room = self.sender.knot_room()
        left = len(plan.knots) - self.streamed
        if room and left:
            for message in plan.knot_messages(self.streamed, min(room, left)):
                self._knot_requests.append(self.sender.send(message))
                self.streamed += message.count
        return self.streamed
