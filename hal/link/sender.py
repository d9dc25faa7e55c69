"""The host's side of the host link's retransmit rule (docs/host-link.md, "Acknowledge and retransmit").

Requests (host -> controller) carry SEQ 0..255, wrapping. A request is sent only while its SEQ is
less than WINDOW past the oldest one not answered (answers may come out of order when some are lost:
the window is of SEQs, so the controller still keeps the result of every request in it). The controller executes a request only when its SEQ is the one it expects, once: a
retransmitted request it already executed gets its kept result again (firmware/link's
link_server_accept). Every request is answered: HELLO by HELLO_REPLY, the others by RESULT.

- A request with no answer TIMEOUT s after it was sent: every request in flight is sent again, in
  order (go-back-N: the controller drops what comes after a gap).
- A RESULT with the link's E_ORDER code is a NAK (a gap: a request was lost); the requests in
  flight not answered are sent again at once, at most once per ROUND_TRIP.
- Every frame of the controller carries its ACK, the next SEQ it expects (telemetry, 1 kHz, too): a
  request below it, unanswered ROUND_TRIP after its sending, was executed and its answer lost: it is
  sent again alone (the controller answers it again without executing it).
- RETRIES timeouts in a row with no answer to any request: the controller is gone (LinkTimeoutError;
  a request is then sent 1 + RETRIES times).
- HELLO starts a session (the controller takes its SEQ as the next expected) and goes alone: no
  other request is sent while it is in flight.

Flow control: the controller reports its free knot slots (`credits`) in every telemetry frame and
in RESULTs; `knot_room()` is the last report less the knots sent that the report did not count (those
in requests at or past its ACK), so the host never sends more knots than fit, and a motion longer
than the buffer plays as the controller frees slots. A RESULT's credits count only when it answers
the last request the controller executed (SEQ = ACK - 1): a repeated older one is stale.

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
ROUND_TRIP = 0.004     # s: a window of requests (8 x 160 bytes, 6.4 ms at most, 20 bytes a command: 0.8 ms)
                       # and its answers within a 1 ms tick


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
        self._stalls = 0                      # timeouts since the last answer
        self._their_seq = None
        self._their_ack = None
        self.credits = None                   # free knot slots, as last reported
        self._credits_ack = 0                 # the ACK of that report
        self._knots_sent: deque[tuple[int, int]] = deque()   # (SEQ, knots) of the KNOTS requests

    # ---- requests ----------------------------------------------------------------------------

    def send(self, message) -> Request:
        """Queue a request; it goes as soon as the window lets it. Returns it (its answer lands in
        request.answer)."""
        type_, payload = ms.pack(message)
        if type_ >= 0x80:
            raise fr.LinkError(f"host link: {type(message).__name__} is the controller's message, not a request")
        request = Request(self._next, type_, payload, message)
        if type_ == ms.KNOTS:
            self._knots_sent.append((request.seq, message.count))
        self._next = (self._next + 1) & 0xFF
        self._queue.append(request)
        self._pump()
        return request

    @property
    def idle(self) -> bool:
        self._pump()
        return not self._flight and not self._queue

    def _pump(self) -> None:
        while self._flight and self._flight[0].answer is not None:
            self._flight.popleft()            # the window slides past the answered
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
            if request.answer is None:
                self._transmit(request)

    def poll(self) -> None:
        """Retransmit on a timeout; LinkTimeoutError after RETRIES of them in a row without an answer."""
        self._pump()
        if not self._flight:
            return
        oldest, now = self._flight[0], self._clock()
        if self._their_ack is not None:
            for request in self._flight:        # executed (below the ACK), its answer lost
                if not 1 <= (self._their_ack - request.seq) & 0xFF <= self.window:
                    break
                if request.answer is None and now - request.sent_at >= ROUND_TRIP:
                    self._transmit(request)
        if now - oldest.sent_at < self.timeout:
            return
        if self._stalls >= self.retries:
            raise LinkTimeoutError(f"host link: the controller answered nothing over {self._stalls + 1} sendings "
                                   f"of request {oldest.seq} ({ms.LAYOUTS[oldest.type][0]}), "
                                   f"{(self._stalls + 1) * self.timeout * 1000:.0f} ms")
        self._stalls += 1
        self._go_back()

    def knot_room(self) -> int:
        """Knots that may be sent now: the last credits reported less the knots sent since that the
        report did not count (0 before any report)."""
        if self.credits is None:
            return 0
        while self._knots_sent and 1 <= (self._credits_ack - self._knots_sent[0][0]) & 0xFF <= 128:
            self._knots_sent.popleft()        # executed before the report: counted in it
        return max(0, self.credits - sum(count for _, count in self._knots_sent))

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
            self._their_ack = f.ack
            self.ack = (f.seq + 1) & 0xFF
            try:
                message = ms.unpack(f.type, f.payload)
            except fr.LinkError:
                continue                      # a good CRC and a bad shape: a broken controller; skip
            if isinstance(message, ms.Telemetry) or (
                    isinstance(message, ms.Result) and message.code != ms.E_ORDER and message.seq == (f.ack - 1) & 0xFF):
                self.credits, self._credits_ack = message.credits, f.ack
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
            if request.answer is None and request.type == type_ and matches(request):
                request.answer = answer
                self.answers[request.seq] = answer
                self._stalls = 0
                break
        self._pump()

    def _on_result(self, result) -> None:
        if result.stage == 0 and result.code == ms.E_ORDER:
            self.naks += 1
            if self._flight and self._clock() - self._last_goback >= ROUND_TRIP:
                self._go_back()
            return
        self._complete(result.type, result, lambda r: r.seq == result.seq)
