"""A bus of virtual servos that answers Protocol 2.0 byte streams as the e-manual defines.

``VirtualBus.handle(data, time)`` takes whatever bytes the host sent (any chunking, garbage
included) and returns the status bytes the servos put on the wire. Replies follow Status Return
Level (0: ping only, 1: ping and reads, 2: all); broadcast instructions other than ping and the
sync/bulk reads get none. Return Delay Time is reported in each ``Reply`` but never waited for.
"""

from __future__ import annotations

import time as _time
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass

from servodyn.hal.dynamixel import (ALERT_BIT, BROADCAST_ID, BadFrame, BadParameters, ErrorNumber, crc16,
                                    Fault, Instruction, InstructionPacket, PacketReader,
                                    ResetOption, StatusError, StatusPacket)
from servodyn.hal.dynamixel import instructions as inst
from servodyn.hal.dynamixel.instructions import fast_reply_frame, seal_fast_reply
from servodyn.hal.dynamixel.reader import BYTE_TIMEOUT
from servodyn.hal.errors import ProtocolError

from .chain import ServoChain
from .servo import Servo

READS = frozenset({Instruction.READ, Instruction.SYNC_READ, Instruction.FAST_SYNC_READ,
                   Instruction.BULK_READ, Instruction.FAST_BULK_READ})
COMMANDS = frozenset({Instruction.SYNC_WRITE, Instruction.BULK_WRITE})   # end a host's control tick
FAST_READS = frozenset({Instruction.FAST_SYNC_READ, Instruction.FAST_BULK_READ})
FAST_FRAMES_KEPT = 8     # fast read replies laid out in advance, one per request seen lately
COMMAND_SHAPE = 12       # header, ID, LEN, instruction, address and data length of a SYNC WRITE
STUFFED = b"\xFF\xFF\xFD"  # what byte stuffing follows with FD


@dataclass(frozen=True)
class Reply:
    servo_id: int              # 0xFE for a fast read reply
    data: bytes                # the encoded status packet
    delay: float               # the servo's Return Delay Time, s (metadata)


@dataclass(frozen=True)
class Exchange:
    """One instruction packet and what the bus answered; passed to ``on_instruction``."""
    request: InstructionPacket
    replies: tuple[Reply, ...]
    time: float


class _Policy:
    """A servo's reply settings as the instruction arrived (a reboot or reset answers first)."""

    def __init__(self, servo: Servo):
        self.level = servo.status_return_level
        self.alert = ALERT_BIT if servo.alert else 0
        self.delay = servo.return_delay
        self.silent = servo.silent

    def answers(self, instruction: int) -> bool:
        return _answers(self.silent, self.level, instruction)


def _answers(silent: bool, level: int, instruction: int) -> bool:
    """Whether a servo answers an instruction, by its Status Return Level."""
    if silent:
        return False
    if instruction == Instruction.PING:
        return True
    return level == 2 or (level == 1 and instruction in READS)


def _parsed(parser: Callable, params: bytes):
    try:
        return parser(params)
    except BadParameters:
        raise StatusError(ErrorNumber.DATA_LENGTH) from None


class VirtualBus:
    """Servos on one simulated bus. ``clock`` gives the time when ``handle``/``tick`` get none;
    ``on_command()`` is called after every command transaction (a sync or bulk write, which ends a
    host's control tick), then ``on_instruction(exchange)`` after every instruction packet is
    answered. A frame whose bytes arrive more than ``byte_timeout`` apart is dropped, as a servo
    does (None: never), timed by ``wire_clock`` when the bytes come over a real-time wire while
    the servos' clock is a simulated one (None: the servos' clock). ``chain``: the servos as one
    (ServoChain, built from them unless given), which clocks them and writes their Present
    registers at once while ``servos`` still holds just its servos."""

    def __init__(self, servos: Iterable[Servo] = (), *, clock: Callable[[], float] = _time.monotonic,
                 on_instruction: Callable[[Exchange], None] | None = None,
                 byte_timeout: float | None = BYTE_TIMEOUT, wire_clock: Callable[[], float] | None = None,
                 chain: ServoChain | None = None):
        self.servos = list(servos)
        self.chain = ServoChain.of(self.servos) if chain is None else chain
        self.clock = clock
        self.wire_clock = wire_clock
        self.on_instruction = on_instruction
        self.on_command: Callable[[], None] | None = None
        self.reader = PacketReader(byte_timeout)
        self.faults: Counter[Fault] = Counter()
        self.unanswerable = 0          # instructions whose answer cannot be encoded
        self._fast_frames: dict[tuple, tuple] = {}   # request -> reply laid out
        self._command: tuple[bytes, int] | None = None   # the last whole SYNC WRITE chunk's shape and size
        self._sync_request: tuple = (None, None)          # the last SYNC READ packet and its requests
        self._fast_request: tuple = (None, None)          # the last fast read's requests, laid out
        self._handlers = {
            Instruction.PING: self._ping, Instruction.READ: self._read, Instruction.WRITE: self._write,
            Instruction.REG_WRITE: self._reg_write, Instruction.ACTION: self._action,
            Instruction.FACTORY_RESET: self._factory_reset, Instruction.REBOOT: self._reboot,
            Instruction.CLEAR: self._clear, Instruction.SYNC_READ: self._sync_read,
            Instruction.FAST_SYNC_READ: self._sync_read, Instruction.SYNC_WRITE: self._sync_write,
            Instruction.BULK_READ: self._bulk_read, Instruction.FAST_BULK_READ: self._bulk_read,
            Instruction.BULK_WRITE: self._bulk_write,
        }

    def servo(self, servo_id: int) -> Servo:
        found = self._primary(servo_id)
        if found is None:
            raise KeyError(f"no servo with ID {servo_id}")
        return found

    def tick(self, time: float | None = None) -> None:
        """Advance every servo's clock (bus watchdog, Realtime Tick) without traffic."""
        now = self.clock() if time is None else time
        if self.chain.covers(self.servos):
            self.chain.clock(now)
            return
        for servo in self.servos:
            # a servo clocked at `now` already has since heard a packet (silent 0) or nothing:
            # clocking it again at the same time would change nothing
            if servo.clocked_at != now:
                servo.clock(now)

    def handle(self, data: bytes, time: float | None = None) -> bytes:
        """Bytes from the host in, the servos' status bytes out."""
        now = self.clock() if time is None else time
        self.tick(now)
        out = []
        events = self._repeated_command(data)
        if events is None:
            pending = self.reader.pending
            events = self.reader.feed(data, now if self.wire_clock is None else self.wire_clock())
            if not pending:
                self._remember_command(data, events)
        for event in events:
            if isinstance(event, BadFrame):
                self.faults[event.fault] += 1
                if event.fault is Fault.CRC:
                    out += self._crc_error(event)
            elif isinstance(event, InstructionPacket):
                try:
                    replies = self._execute(event, now)
                except ProtocolError:
                    # an answer the wire cannot carry (a fast reply of over 65,535 bytes): a
                    # real chain garbles it; here nobody answers, and it is counted
                    self.unanswerable += 1
                    replies = []
                out += replies
                if self.on_command is not None and event.instruction in COMMANDS:
                    self.on_command()
                if self.on_instruction is not None:
                    self.on_instruction(Exchange(event, tuple(replies), now))
        return b"".join(reply.data for reply in out)

    def _repeated_command(self, data: bytes) -> list[InstructionPacket] | None:
        """A chunk that is one broadcast SYNC WRITE frame of the last whole one's shape (its first
        COMMAND_SHAPE bytes and its size: the host's command of every tick, new values in the same
        blocks), with a good CRC and nothing stuffed: its packet, as the reader would parse it,
        without the parse; None for anything else (the reader's)."""
        shape = self._command
        if (shape is None or len(data) != shape[1] or not isinstance(data, (bytes, bytearray))
                or not data.startswith(shape[0]) or self.reader.pending
                or data.find(STUFFED, 7, len(data) - 2) >= 0 or crc16(data[:-2]) != data[-2] | data[-1] << 8):
            return None
        return [InstructionPacket(BROADCAST_ID, data[7], bytes(data[8:-2]))]

    def _remember_command(self, data: bytes, events: list) -> None:
        """The shape of a chunk that was one whole broadcast SYNC WRITE, for _repeated_command."""
        if (len(events) == 1 and isinstance(events[0], InstructionPacket) and events[0].id == BROADCAST_ID
                and events[0].instruction == Instruction.SYNC_WRITE and not self.reader.pending
                and len(data) > COMMAND_SHAPE + 2):
            self._command = (bytes(data[:COMMAND_SHAPE]), len(data))

    # --- dispatch ------------------------------------------------------------------------------------

    def _primary(self, servo_id: int) -> Servo | None:
        for servo in self.servos:
            if servo.id == servo_id:
                return servo
        return None

    def _execute(self, packet: InstructionPacket, now: float) -> list[Reply]:
        broadcast = packet.id == BROADCAST_ID
        targets = self.servos if broadcast else [s for s in self.servos
                                                 if packet.id in (s.id, s.get("secondary_id"))]
        if broadcast and self.chain.covers(targets):
            self.chain.heard(now)
        else:
            for servo in targets:
                servo.heard(now)
        handler = self._handlers.get(packet.instruction)
        if handler is None:
            return self._each(packet, targets, lambda s: _raise(ErrorNumber.INSTRUCTION))
        return handler(packet, targets)

    def _status(self, policy: _Policy, servo_id: int, instruction: int,
                error: int = 0, params: bytes = b"") -> list[Reply]:
        if not policy.answers(instruction):
            return []
        packet = StatusPacket(servo_id, error | policy.alert, params)
        return [Reply(servo_id, packet.encode(), policy.delay)]

    def _each(self, packet: InstructionPacket, targets: list[Servo], act: Callable[[Servo], bytes | None]):
        """Run ``act`` on every target; only the servo addressed by its own ID answers, and only a
        unicast instruction gets an answer (the secondary ID executes silently)."""
        replies = []
        for servo in targets:
            answers = packet.id != BROADCAST_ID and servo.id == packet.id
            policy = _Policy(servo)
            try:
                params, error = act(servo) or b"", 0
            except StatusError as refused:
                params, error = b"", refused.error
            if answers:
                replies += self._status(policy, packet.id, packet.instruction, error, params)
        return replies

    def _crc_error(self, frame: BadFrame) -> list[Reply]:
        servo = self._primary(frame.id) if frame.id != BROADCAST_ID else None
        if servo is None:
            return []
        return self._status(_Policy(servo), servo.id, frame.instruction, ErrorNumber.CRC)

    # --- single-servo instructions -----------------------------------------------------------------

    def _ping(self, packet, targets):
        if packet.id != BROADCAST_ID:
            return self._each(packet, targets, lambda s: s.ping_reply())
        replies = []
        for servo in sorted(self.servos, key=lambda s: s.id):     # every servo, in ID order
            replies += self._status(_Policy(servo), servo.id, Instruction.PING, 0, servo.ping_reply())
        return replies

    def _read(self, packet, targets):
        if packet.id == BROADCAST_ID:                                 # READ is not executed by broadcast
            return []
        return self._each(packet, targets, lambda s: s.read(*_parsed(inst.parse_read, packet.params)))

    def _write(self, packet, targets):
        return self._each(packet, targets, lambda s: s.write(*_parsed(inst.parse_write, packet.params)))

    def _reg_write(self, packet, targets):
        return self._each(packet, targets, lambda s: s.reg_write(*_parsed(inst.parse_write, packet.params)))

    def _action(self, packet, targets):
        return self._each(packet, targets, lambda s: _no_params(packet) or s.action())

    def _reboot(self, packet, targets):
        return self._each(packet, targets, lambda s: _no_params(packet) or s.reboot())

    def _factory_reset(self, packet, targets):
        if packet.id == BROADCAST_ID and packet.params == bytes([ResetOption.ALL]):
            return []                                                 # refused by design (FW 42+)

        def reset(servo):
            if len(packet.params) != 1:
                _raise(ErrorNumber.DATA_LENGTH)
            servo.factory_reset(packet.params[0])
        return self._each(packet, targets, reset)

    def _clear(self, packet, targets):
        def clear(servo):
            if len(packet.params) != len(inst.CLEAR_MULTI_TURN):
                _raise(ErrorNumber.DATA_LENGTH)
            if packet.params != inst.CLEAR_MULTI_TURN:
                _raise(ErrorNumber.DATA_RANGE)
            servo.clear_multi_turn()
        return self._each(packet, targets, clear)

    # --- sync and bulk instructions (broadcast only) ----------------------------------------------

    def _sync_read(self, packet, targets):
        if packet.id != BROADCAST_ID:
            return self._each(packet, targets, lambda s: _raise(ErrorNumber.INSTRUCTION))
        last, requests = self._sync_request
        if packet is not last:             # the reader gives a repeated request's packet again
            try:
                address, length, ids = inst.parse_sync_read(packet.params)
            except BadParameters:
                return []
            requests = [(i, address, length) for i in ids]
            self._sync_request = (packet, requests)
        return self._reads(packet.instruction, requests)

    def _bulk_read(self, packet, targets):
        if packet.id != BROADCAST_ID:
            return self._each(packet, targets, lambda s: _raise(ErrorNumber.INSTRUCTION))
        try:
            requests = inst.parse_bulk_read(packet.params)
        except BadParameters:
            return []
        return self._reads(packet.instruction, requests)

    def _reads(self, instruction: int, requests: list[tuple[int, int, int]]) -> list[Reply]:
        """Each listed servo answers in request order; a fast read answers in one packet."""
        if instruction in FAST_READS:
            return self._fast_reads(instruction, requests)
        replies = []
        for servo_id, address, length in requests:
            servo = self._primary(servo_id)
            policy = _Policy(servo) if servo is not None else None
            if policy is None or not policy.answers(instruction):
                continue
            try:
                data, error = servo.read(address, length), 0
            except StatusError as refused:
                data, error = b"", refused.error
            replies += self._status(policy, servo_id, instruction, error, data)
        return replies

    def _fast_reads(self, instruction: int, requests: list[tuple[int, int, int]]) -> list[Reply]:
        """One packet, and none when a listed servo is missing or does not answer reads. A silent
        servo (a fault) cuts the reply where its block would begin, as on a chain: the servos
        before it answered, the ones after wait for it and never do, and the header's LEN still
        counts every block, so the host sees a short packet (nothing at all if the first is
        silent). The reply is filled in place in a frame laid out once per request, by the chain
        when it is one span of every servo's."""
        frame, starts, ids, span, lengths = self._fast_frame(requests)
        if span is not None and self.chain.covers(self.servos):
            filled = self.chain.fast_read(ids, *span, frame, starts)
            if filled != -2:
                if filled <= 0:
                    return []
                seal_fast_reply(frame, lengths if filled == len(lengths) else lengths[:filled])
                first = self._primary(ids[0])
                return [Reply(BROADCAST_ID, bytes(memoryview(frame)[:starts[filled]]), first.return_delay)]
        answering = []
        present = [servo.id for servo in self.servos]
        for servo_id, _, _ in requests:
            servo = self.servos[present.index(servo_id)] if servo_id in present else None   # _primary
            if servo is not None and servo.silent:
                break
            if servo is None or not _answers(False, servo.status_return_level, instruction):
                return []
            answering.append(servo)
        if not answering:
            return []
        for servo, (_, address, length), start in zip(answering, requests, starts):
            alert = ALERT_BIT if servo.alert else 0
            try:
                servo.read_into(frame, start + 2, address, length)
                error = 0
            except StatusError as refused:
                frame[start + 2:start + 2 + length] = bytes(length)
                error = refused.error
            frame[start] = error | alert
        seal_fast_reply(frame, [length for _, _, length in requests[:len(answering)]])
        end = starts[len(answering)]          # the whole frame, or where the silent servo's block begins
        return [Reply(BROADCAST_ID, bytes(memoryview(frame)[:end]), answering[0].return_delay)]

    def _fast_frame(self, requests: list[tuple[int, int, int]]) -> tuple[bytearray, list[int], bytes, tuple | None,
                                                                      list[int]]:
        """The reply to a fast read laid out (instructions.fast_reply_frame) and where each block
        begins, the frame's end last, the IDs, (address, length) when every block reads the same
        span, and each block's length; kept for the next time the same request comes."""
        if requests is self._fast_request[0]:        # the same request's list (_sync_read keeps it)
            return self._fast_request[1]
        key = tuple(requests)
        laid_out = self._fast_frames.get(key)
        if laid_out is None:
            frame = fast_reply_frame([i for i, _, _ in requests], [n for _, _, n in requests])
            starts = [inst.FAST_BLOCKS_START]
            for _, _, length in requests:
                starts.append(starts[-1] + length + 4)
            spans = {(address, length) for _, address, length in requests}
            if len(self._fast_frames) >= FAST_FRAMES_KEPT:
                self._fast_frames.clear()
            laid_out = self._fast_frames[key] = (frame, starts, bytes(i for i, _, _ in requests),
                                                 spans.pop() if len(spans) == 1 else None,
                                                 [length for _, _, length in requests])
        self._fast_request = (requests, laid_out)
        return laid_out

    def _sync_write(self, packet, targets):
        if packet.id != BROADCAST_ID:
            return self._each(packet, targets, lambda s: _raise(ErrorNumber.INSTRUCTION))
        params = packet.params
        if len(params) >= 4 and self.chain.covers(self.servos) and self.chain.write(
                params[0] | params[1] << 8, params[2] | params[3] << 8, params):
            return []
        try:
            address, writes = inst.parse_sync_write(params)
        except BadParameters:
            return []
        self._writes([(servo_id, address, data) for servo_id, data in writes])
        return []

    def _bulk_write(self, packet, targets):
        if packet.id != BROADCAST_ID:
            return self._each(packet, targets, lambda s: _raise(ErrorNumber.INSTRUCTION))
        try:
            self._writes(inst.parse_bulk_write(packet.params))
        except BadParameters:
            pass
        return []

    def _writes(self, writes: list[tuple[int, int, bytes]]) -> None:
        """Broadcast writes: a refused block is dropped silently, the others still apply."""
        answering: dict[int, list[Servo]] = {}        # by ID (primary or secondary) as they were
        for servo in self.servos:
            primary, secondary = servo.id, servo.get("secondary_id")
            answering.setdefault(primary, []).append(servo)
            if secondary != primary:
                answering.setdefault(secondary, []).append(servo)
        for servo_id, address, data in writes:
            for servo in answering.get(servo_id, ()):
                try:
                    servo.write(address, data)
                except StatusError:
                    pass


def _raise(number: ErrorNumber):
    raise StatusError(number)


def _no_params(packet: InstructionPacket) -> None:
    if packet.params:
        _raise(ErrorNumber.DATA_LENGTH)
