"""The host's side of the host link's retransmit rule (docs/host-link.md, "Acknowledge and retransmit").

Requests (host -> controller) carry SEQ 0..255, wrapping. At most WINDOW are in flight (sent, not
answered). The controller executes a request only when its SEQ is the one it expects, once: a
retransmitted request it already executed gets its kept result again (firmware/link's
link_server_accept). Every request is answered: HELLO by HELLO_REPLY, the others by RESULT.

- A request with no answer TIMEOUT s after it was sent: every request in flight is sent again, in
  order (go-back-N: the controller drops what comes after a gap).
- A RESULT with the link's E_ORDER code is a NAK (a gap: a request was lost); the requests in
  flight are sent again at once, at most once per TIMEOUT / 4.
- A request sent 1 + RETRIES times without an answer: the controller is gone (LinkTimeoutError).
- HELLO starts a session (the controller takes its SEQ as the next expected) and goes alone: no
  other request is sent while it is in flight.

The controller's frames are not retransmitted: telemetry is news, a lost one is skipped (its SEQ
counts the losses), and a lost RESULT is made good by the request's retransmission.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass

from ...errors import ExitCode
from . import frame as fr
from . import messages as ms

WINDOW = 8             # requests in flight; the controller keeps as many results (LINK_WINDOW)
TIMEOUT = 0.025        # s: at 2 Mbps a full frame takes 1.25 ms each way and the controller
                       # answers within a tick (1 ms): a round trip is under 5 ms; Klipper's floor is 25 ms
RETRIES = 8            # 9 sendings over 225 ms: over a host watchdog's 100 ms, the run is lost anyway


class LinkVersionError(fr.LinkError):
    """The controller speaks another version of the host link."""
    exit_code = ExitCode.SETUP


class LinkTimeoutError(fr.LinkError, TimeoutError):
    """The controller answered no retransmission of a request."""
    exit_code = ExitCode.TIMEOUT


def version_error(theirs: int) -> LinkVersionError:
    return LinkVersionError(f"host link version mismatch: the controller speaks version {theirs}, this host "
                            f"version {fr.VERSION}: flash the firmware of this servodyn, or use the servodyn "
                            f"of that firmware")


@dataclass
class Request:
    seq: int
    type: int
    payload: bytes
    message: object
    sent_at: float = -1.0
    sendings: int = 0
    answer: object = None        # the RESULT (or HELLO_REPLY) once it came


class Sender:
    """Requests out through write(bytes), the controller's bytes in through receive(); poll() runs
    the timeouts. Answers land in `answers` by SEQ; other messages (telemetry) come back from
    receive()."""

    def __init__(self, write, clock=time.monotonic, window: int = WINDOW, timeout: float = TIMEOUT,
                 retries: int = RETRIES):
        self._write, self._clock = write, clock
        self.window, self.timeout, self.retries = window, timeout, retries
        self.decoder = fr.Decoder()
        self._next = 0
        self.ack = 0                          # the next SEQ expected from the controller
        self._flight: deque[Request] = deque()
        self._queue: deque[Request] = deque()
        self.answers: dict[int, object] = {}
        self.sendings = 0                     # frames sent, first sendings and retransmissions
        self.retransmissions = 0
        self.naks = 0
        self.lost_from_controller = 0         # controller frames missed (gaps in their SEQ)
        self._last_goback = -1e9
        self._their_seq = None

    # ---- requests ----------------------------------------------------------------------------

    def send(self, message) -> Request:
        """Queue a request; it goes as soon as the window lets it. Returns it (its answer lands in
        request.answer)."""
        type_, payload = ms.pack(message)
        if type_ >= 0x80:
            raise fr.LinkError(f"host link: {type(message).__name__} is the controller's message, not a request")
        request = Request(self._next, type_, payload, message)
        self._next = (self._next + 1) & 0xFF
        self._queue.append(request)
        self._pump()
        return request

    @property
    def idle(self) -> bool:
        return not self._flight and not self._queue

    def _pump(self) -> None:
        while self._queue and len(self._flight) < self.window:
            if any(r.type == ms.HELLO for r in self._flight):
                return                        # a session starts alone
            if self._queue[0].type == ms.HELLO and self._flight:
                return
            request = self._queue.popleft()
            self._flight.append(request)
            self._transmit(request)

    def _transmit(self, request: Request) -> None:
        self._write(fr.encode(request.seq, self.ack, request.type, request.payload))
        request.sent_at = self._clock()
        request.sendings += 1
        self.sendings += 1
        if request.sendings > 1:
            self.retransmissions += 1

    def _go_back(self) -> None:
        self._last_goback = self._clock()
        for request in list(self._flight):
            self._transmit(request)

    def poll(self) -> None:
        """Retransmit on a timeout; LinkTimeoutError once a request has had all its sendings."""
        if not self._flight:
            self._pump()
            return
        oldest = self._flight[0]
        if self._clock() - oldest.sent_at < self.timeout:
            return
        if oldest.sendings > self.retries:
            raise LinkTimeoutError(f"host link: the controller answered none of {oldest.sendings} sendings of "
                                   f"request {oldest.seq} ({ms.LAYOUTS[oldest.type][0]}) over "
                                   f"{oldest.sendings * self.timeout * 1000:.0f} ms")
        self._go_back()

    # ---- the controller's frames -------------------------------------------------------------

    def receive(self, data: bytes) -> list:
        """Take the controller's bytes: answers complete their requests; every other message
        (telemetry) is returned. A frame of another version: LinkVersionError."""
        out = []
        for f in self.decoder.feed(data):
            if f.verdict == fr.BAD_VERSION:
                raise version_error(f.version)
            if f.verdict != fr.FRAME:
                continue
            if self._their_seq is not None:
                self.lost_from_controller += (f.seq - self._their_seq - 1) & 0xFF
            self._their_seq = f.seq
            self.ack = (f.seq + 1) & 0xFF
            try:
                message = ms.unpack(f.type, f.payload)
            except fr.LinkError:
                continue                      # a good CRC and a bad shape: a broken controller; skip
            if isinstance(message, ms.Result):
                self._on_result(message)
            elif isinstance(message, ms.HelloReply):
                if message.link_version != fr.VERSION:
                    raise version_error(message.link_version)
                self._complete(ms.HELLO, message, lambda r: r.message.nonce == message.nonce)
                out.append(message)
            else:
                out.append(message)
        self._pump()
        return out

    def _complete(self, type_: int, answer, matches) -> None:
        for request in self._flight:
            if request.type == type_ and matches(request):
                request.answer = answer
                self.answers[request.seq] = answer
                self._flight.remove(request)
                return

    def _on_result(self, result) -> None:
        if result.stage == 0 and result.code == ms.E_ORDER:
            self.naks += 1
            if self._flight and self._clock() - self._last_goback >= self.timeout / 4:
                self._go_back()
            return
        self._complete(result.type, result, lambda r: r.seq == result.seq)
