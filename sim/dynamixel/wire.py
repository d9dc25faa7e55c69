"""A bus of virtual servos that answers Protocol 2.0 byte streams as the e-manual defines.

``DynamixelWire.handle(data, time)`` takes whatever bytes the host sent (any chunking, garbage
included) and returns the status bytes the servos put on the wire. Replies follow Status Return
Level (0: ping only, 1: ping and reads, 2: all); broadcast instructions other than ping and the
sync/bulk reads get none. Return Delay Time is reported in each ``Reply`` but never waited for.

Line speed: with ``line_speed`` set (bit/s, the speed the host's port runs at; a PtyServer sets it
from its pseudo-terminal) a servo hears only the bytes sent at its own speed (``Servo.baud``, its
Baud Rate register's) and answers at it; bytes no servo listens at are dropped and counted by
speed in ``unheard``, and a frame cut by a change of speed is dropped as a truncated one. None:
every servo hears everything (a bus driven in-process).

Collisions: several servos that answer one instruction at once — the same ID twice on the bus
(factory-fresh servos all say ID 1), or a fast read that an old firmware refuses while the others
answer — talk over each other on the half-duplex wire. The host receives one packet: the bitwise
AND of their bytes, each aligned at its first byte (a low bit wins on the line; past the end of the
shorter the line idles high), and never one that checks: where the AND would still be a good packet
(identical replies, as seven fresh servos' pings are) its CRC's last byte is inverted, since two
servos' UARTs never start on the same bit (`collide`). Replies at different IDs to a broadcast
ping do not collide: each servo waits its turn by ID, as on the real bus.
"""

from __future__ import annotations

import time as _time
from collections import Counter
from collections.abc import Callable, Iterable

from servodyn.hal.dynamixel import (BROADCAST_ID, BadFrame, BadParameters, ErrorNumber, crc16,
                                    Fault, Instruction, InstructionPacket, PacketReader,
                                    ResetOption, StatusError, StatusPacket)
from servodyn.hal.dynamixel import instructions as inst
from servodyn.hal.dynamixel.control_table import FAST_READ_FIRMWARE, SIMULATOR_CLOCK_ADDRESS, SIMULATOR_CLOCKS
from servodyn.hal.dynamixel.instructions import fast_reply_frame
from servodyn.hal.dynamixel.reader import BYTE_TIMEOUT
from servodyn.hal.errors import ProtocolError

from .chain import ServoChain
from .replies import Exchange, Policy, Reply, collide, collided, fast_replies  # collide: the module's model
from .servo import Servo

COMMANDS = frozenset({Instruction.SYNC_WRITE, Instruction.BULK_WRITE})   # end a host's control tick
FAST_READS = frozenset({Instruction.FAST_SYNC_READ, Instruction.FAST_BULK_READ})
FAST_FRAMES_KEPT = 8     # fast read replies laid out in advance, one per request seen lately
COMMAND_SHAPE = 12       # header, ID, LEN, instruction, address and data length of a SYNC WRITE
STUFFED = b"\xFF\xFF\xFD"  # what byte stuffing follows with FD


def _parsed(parser: Callable, params: bytes):
    try:
        return parser(params)
    except BadParameters:
        raise StatusError(ErrorNumber.DATA_LENGTH) from None


class DynamixelWire:
    """Servos on one simulated bus. ``clock`` gives the time when ``handle``/``tick`` get none;
    ``on_command()`` is called after every command transaction (a sync or bulk write, which ends a
    host's control tick), then ``on_instruction(exchange)`` after every instruction packet is
    answered. A frame whose bytes arrive more than ``byte_timeout`` apart is dropped, as a servo
    does (None: never), timed by ``wire_clock`` when the bytes come over a real-time wire while
    the servos' clock is a simulated one (None: the servos' clock). ``chain``: the servos as one
    (ServoChain, built from them unless given: the plant's too when one bus holds them all), which
    clocks them."""

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
        # the clock the bus is served on ("lockstep", "realtime"), answered at SIMULATOR_CLOCK_ADDRESS
        self.served_clock: str | None = None
        self.line_speed: int | None = None   # bit/s of the host's bytes; None: every servo hears them
        self.unheard: Counter[int] = Counter()   # bytes no servo listened at, by their speed
        self._heard_speed: int | None = None  # the line speed of the last bytes fed to the reader
        # who listens at what, cached until a servo's ID, Baud Rate or EEPROM changes (_rewire)
        self._wiring: tuple | None = None
        self._speed: int | None = None   # the one speed every servo listens at (None: several)
        self._shared = False             # two servos hold one ID
        self._plain = True               # no ID shared, every firmware takes fast reads
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
        if not self.chain.covers(self.servos):       # the bus's servos changed since
            self.chain = ServoChain(self.servos)
        self.chain.clock(self.clock() if time is None else time)

    def _rewire(self) -> None:
        """Who listens at which speed, whether an ID is shared, whether every firmware takes fast
        reads: as the servos stand now (each servo's speed its Baud Rate register's: a write's
        status went out at the old one)."""
        speeds = {servo.listen() for servo in self.servos}
        ids = [servo.id for servo in self.servos]
        self._speed = speeds.pop() if len(speeds) == 1 else None
        self._shared = len(set(ids)) != len(ids)
        self._plain = not self._shared and all(s.get("firmware_version") >= FAST_READ_FIRMWARE for s in self.servos)
        self._wiring = (Servo.wiring, len(self.servos))

    def handle(self, data: bytes, time: float | None = None) -> bytes:
        """Bytes from the host in, the servos' status bytes out."""
        now = self.clock() if time is None else time
        self.tick(now)
        if self._wiring != (Servo.wiring, len(self.servos)):
            self._rewire()
        speed, everyone = self.line_speed, self.servos
        try:
            if speed is None or speed == self._speed:     # every servo hears: the swing's path
                if speed != self._heard_speed:
                    self._speed_changed(speed)
                return self._handle(data, now, everyone)
            return self._handle_at(data, now, speed, everyone)
        finally:
            self.servos = everyone     # _handle_at and a rewiring in the chunk narrow it

    def _speed_changed(self, speed: int | None) -> None:
        """A frame that was arriving at another speed is lost (its end is garbage to the receivers)."""
        self._heard_speed = speed
        for event in self.reader.expire():
            if isinstance(event, BadFrame):
                self.faults[event.fault] += 1

    def _handle_at(self, data: bytes, now: float, speed: int, everyone: list[Servo]) -> bytes:
        """`data` sent at `speed`, which not every servo listens at: the servos that do hear and
        answer it (self.servos, for the call, is them), the bytes nobody hears are counted."""
        self.servos = [servo for servo in everyone if servo.baud == speed]
        if not self.servos:
            self.unheard[speed] += len(data)
            return b""
        if speed != self._heard_speed:
            self._speed_changed(speed)
        return self._handle(data, now, everyone)

    def _handle(self, data: bytes, now: float, everyone: list[Servo]) -> bytes:
        """handle()'s work on the servos that hear `data` (self.servos; `everyone`: the whole bus)."""
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
                    replies = self._crc_error(event)
                    out += collided(replies) if len(replies) > 1 else replies
            elif isinstance(event, InstructionPacket):
                try:
                    replies = self._execute(event, now)
                except ProtocolError:
                    # an answer the wire cannot carry (a fast reply of over 65,535 bytes): a
                    # real chain garbles it; here nobody answers, and it is counted
                    self.unanswerable += 1
                    replies = []
                if self._shared and len(replies) > 1:
                    replies = collided(replies)
                out += replies
                if Servo.wiring != self._wiring[0]:
                    self._rewired_in_chunk(everyone)
                if self.on_command is not None and event.instruction in COMMANDS:
                    self.on_command()
                if self.on_instruction is not None:
                    self.on_instruction(Exchange(event, tuple(replies), now))
        return b"".join(reply.data for reply in out)

    def _rewired_in_chunk(self, everyone: list[Servo]) -> None:
        """An instruction changed an ID or a Baud Rate (its status already sent, at the old speed):
        the rest of the chunk is heard as the servos now stand."""
        self.servos = everyone
        self._rewire()
        if self.line_speed is not None and self.line_speed != self._speed:
            self.servos = [servo for servo in everyone if servo.baud == self.line_speed]

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
        for servo in targets:
            servo.heard(now)
        handler = self._handlers.get(packet.instruction)
        if handler is None:
            return self._each(packet, targets, lambda s: _raise(ErrorNumber.INSTRUCTION))
        return handler(packet, targets)

    def _status(self, policy: Policy, servo_id: int, instruction: int,
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
            policy = Policy(servo)
            try:
                params, error = act(servo) or b"", 0
            except StatusError as refused:
                params, error = b"", refused.error
            if answers:
                replies += self._status(policy, packet.id, packet.instruction, error, params)
        return replies

    def _crc_error(self, frame: BadFrame) -> list[Reply]:
        if frame.id == BROADCAST_ID:
            return []
        replies = []
        for servo in self._holders(frame.id):
            replies += self._status(Policy(servo), servo.id, frame.instruction, ErrorNumber.CRC)
        return replies

    def _holders(self, servo_id: int) -> list[Servo]:
        """The servos at `servo_id` (one at most unless an ID is shared)."""
        if not self._shared:
            servo = self._primary(servo_id)
            return [] if servo is None else [servo]
        return [servo for servo in self.servos if servo.id == servo_id]

    # --- single-servo instructions -----------------------------------------------------------------

    def _ping(self, packet, targets):
        if packet.id != BROADCAST_ID:
            return self._each(packet, targets, lambda s: s.ping_reply())
        replies = []
        for servo in sorted(self.servos, key=lambda s: s.id):     # every servo, in ID order
            replies += self._status(Policy(servo), servo.id, Instruction.PING, 0, servo.ping_reply())
        return replies

    def _read(self, packet, targets):
        if packet.id == BROADCAST_ID:                                 # READ is not executed by broadcast
            return []

        def read(servo):
            address, length = _parsed(inst.parse_read, packet.params)
            if address == SIMULATOR_CLOCK_ADDRESS and length == 1 and self.served_clock is not None:
                return bytes([next(c for c, clock in SIMULATOR_CLOCKS.items() if clock == self.served_clock)])
            return servo.read(address, length)
        return self._each(packet, targets, read)

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
            for servo in self._holders(servo_id):
                policy = Policy(servo)
                if not policy.answers(instruction):
                    continue
                try:
                    data, error = servo.read(address, length), 0
                except StatusError as refused:
                    data, error = b"", refused.error
                replies += self._status(policy, servo_id, instruction, error, data)
        return replies

    def _fast_reads(self, instruction: int, requests: list[tuple[int, int, int]]) -> list[Reply]:
        """One packet (replies.fast_replies), filled in place in a frame laid out once per request."""
        frame, starts = self._fast_frame(requests)
        return fast_replies(self.servos, self._plain, instruction, requests, frame, starts)

    def _fast_frame(self, requests: list[tuple[int, int, int]]) -> tuple[bytearray, list[int]]:
        """The reply to a fast read laid out (instructions.fast_reply_frame) and where each block
        begins, the frame's end last; kept for the next time the same request comes."""
        if requests is self._fast_request[0]:        # the same request's list (_sync_read keeps it)
            return self._fast_request[1]
        key = tuple(requests)
        laid_out = self._fast_frames.get(key)
        if laid_out is None:
            frame = fast_reply_frame([i for i, _, _ in requests], [n for _, _, n in requests])
            starts = [inst.FAST_BLOCKS_START]
            for _, _, length in requests:
                starts.append(starts[-1] + length + 4)
            if len(self._fast_frames) >= FAST_FRAMES_KEPT:
                self._fast_frames.clear()
            laid_out = self._fast_frames[key] = (frame, starts)
        self._fast_request = (requests, laid_out)
        return laid_out

    def _sync_write(self, packet, targets):
        if packet.id != BROADCAST_ID:
            return self._each(packet, targets, lambda s: _raise(ErrorNumber.INSTRUCTION))
        try:
            address, writes = inst.parse_sync_write(packet.params)
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
