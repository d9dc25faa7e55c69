"""Protocol 2.0 codec against the e-manual's example packets, byte stuffing, and the frame reader
on garbage, split, corrupted and truncated input."""

import random

import pytest

from servodyn.hal.dynamixel import (BROADCAST_ID, BadFrame, BadParameters, CrcMismatch, FastReadBlock,
                                    Fault, FieldRangeError, InstructionPacket, PacketReader, ResetOption,
                                    StatusError, StatusPacket, crc16, decode_frame, encode_fast_reply,
                                    pack_field, split_fast_reply, stuff, unpack_field, unstuff)
from servodyn.hal.dynamixel import instructions as inst


def h(text: str) -> bytes:
    return bytes.fromhex(text)


# The instruction packets of the e-manual's "DYNAMIXEL Protocol 2.0" page, byte for byte.
EMANUAL_INSTRUCTIONS = [
    ("ping ID 1", inst.ping(1), "FF FF FD 00 01 03 00 01 19 4E"),
    ("broadcast ping", inst.ping(), "FF FF FD 00 FE 03 00 01 31 42"),
    ("read Present Position", inst.read(1, 132, 4), "FF FF FD 00 01 07 00 02 84 00 04 00 1D 15"),
    ("write Goal Position 512", inst.write(1, 116, pack_field(512, 4)),
     "FF FF FD 00 01 09 00 03 74 00 00 02 00 00 CA 89"),
    ("reg write Goal Velocity 200", inst.reg_write(1, 104, pack_field(200, 4)),
     "FF FF FD 00 01 09 00 04 68 00 C8 00 00 00 AE 8E"),
    ("action", inst.action(1), "FF FF FD 00 01 03 00 05 02 CE"),
    ("factory reset except ID", inst.factory_reset(1, ResetOption.EXCEPT_ID),
     "FF FF FD 00 01 04 00 06 01 A1 E6"),
    ("reboot", inst.reboot(1), "FF FF FD 00 01 03 00 08 2F 4E"),
    ("clear multi-turn", inst.clear_multi_turn(1), "FF FF FD 00 01 08 00 10 01 44 58 4C 22 B1 DC"),
    ("sync read ID 1, 2", inst.sync_read(132, 4, [1, 2]), "FF FF FD 00 FE 09 00 82 84 00 04 00 01 02 CE FA"),
    ("sync write 150, 170", inst.sync_write(116, 4, {1: pack_field(150, 4), 2: pack_field(170, 4)}),
     "FF FF FD 00 FE 11 00 83 74 00 04 00 01 96 00 00 00 02 AA 00 00 00 82 87"),
    ("fast sync read ID 3, 7, 4", inst.fast_sync_read(132, 4, [3, 7, 4]),
     "FF FF FD 00 FE 0A 00 8A 84 00 04 00 03 07 04 20 F2"),
    ("bulk read", inst.bulk_read([(1, 144, 2), (2, 146, 1)]),
     "FF FF FD 00 FE 0D 00 92 01 90 00 02 00 02 92 00 01 00 1A 05"),
    ("bulk write", inst.bulk_write([(1, 32, h("A0 00")), (2, 31, h("50"))]),
     "FF FF FD 00 FE 10 00 93 01 20 00 02 00 A0 00 02 1F 00 01 00 50 B7 68"),
    # The e-manual prints CRC 20 F2 here, the fast sync read example's CRC copied; every other byte
    # matches, and CRC-16 of them is 0x2DDA.
    ("fast bulk read", inst.fast_bulk_read([(3, 132, 4), (7, 124, 2), (4, 146, 1)]),
     "FF FF FD 00 FE 12 00 9A 03 84 00 04 00 07 7C 00 02 00 04 92 00 01 00 DA 2D"),
]

# The e-manual's status packets: (packet, exact bytes).
EMANUAL_STATUS = [
    (StatusPacket(1, 0, h("06 04 26")), "FF FF FD 00 01 07 00 55 00 06 04 26 65 5D"),
    (StatusPacket(2, 0, h("06 04 26")), "FF FF FD 00 02 07 00 55 00 06 04 26 6F 6D"),
    (StatusPacket(1, 0, pack_field(166, 4)), "FF FF FD 00 01 08 00 55 00 A6 00 00 00 8C C0"),
    (StatusPacket(2, 0, pack_field(2079, 4)), "FF FF FD 00 02 08 00 55 00 1F 08 00 00 BA BE"),
    (StatusPacket(1, 0), "FF FF FD 00 01 04 00 55 00 A1 0C"),
    (StatusPacket(1, 0, pack_field(119, 2)), "FF FF FD 00 01 06 00 55 00 77 00 C3 69"),
    (StatusPacket(2, 0, h("24")), "FF FF FD 00 02 05 00 55 00 24 8B A9"),
]

# Fast read replies: the running CRC after each block (84 08, 16 CA / 67 A4, 24 74) proves that a
# block's CRC covers the packet so far, earlier blocks' CRCs included.
EMANUAL_FAST_SYNC_REPLY = ("FF FF FD 00 FE 19 00 55 00 03 A6 00 00 00 84 08 00 07 1F 08 00 00 16 CA "
                           "00 04 FF 03 00 00 D1 9E")
EMANUAL_FAST_BULK_REPLY = "FF FF FD 00 FE 14 00 55 00 03 A6 00 00 00 67 A4 00 07 A5 01 24 74 00 04 1F D9 C1"


def test_crc16_is_crc16_umts():
    # poly 0x8005, init 0, no reflection, no final xor: the catalogue check value of "123456789"
    assert crc16(b"123456789") == 0xFEE8, "CRC-16/UMTS (BUYPASS) check value"
    assert crc16(h("FF FF FD 00 01 03 00 01")) == 0x4E19, "e-manual: ping ID 1 → CRC 0x4E19"


@pytest.mark.parametrize("name, packet, expected", EMANUAL_INSTRUCTIONS,
                         ids=[e[0] for e in EMANUAL_INSTRUCTIONS])
def test_instruction_packets_match_the_emanual(name, packet, expected):
    assert packet.encode() == h(expected), f"{name}: builder output differs from the e-manual"
    assert decode_frame(h(expected)) == packet, f"{name}: decoding gives back the same packet"


@pytest.mark.parametrize("packet, expected", EMANUAL_STATUS, ids=[e[1][:20] for e in EMANUAL_STATUS])
def test_status_packets_match_the_emanual(packet, expected):
    assert packet.encode() == h(expected), "status packet bytes differ from the e-manual"
    assert decode_frame(h(expected)) == packet, "decoding gives back ID, ERR and parameters"


def test_fast_sync_read_reply_matches_the_emanual():
    blocks = [FastReadBlock(3, 0, pack_field(166, 4)), FastReadBlock(7, 0, pack_field(2079, 4)),
              FastReadBlock(4, 0, pack_field(1023, 4))]
    assert encode_fast_reply(blocks) == h(EMANUAL_FAST_SYNC_REPLY), "one packet, per-block running CRC"
    packet = decode_frame(h(EMANUAL_FAST_SYNC_REPLY))
    assert split_fast_reply(packet, [4, 4, 4]) == blocks, "the reply splits back into the three blocks"


def test_fast_bulk_read_reply_matches_the_emanual():
    blocks = [FastReadBlock(3, 0, pack_field(166, 4)), FastReadBlock(7, 0, pack_field(421, 2)),
              FastReadBlock(4, 0, h("1F"))]
    assert encode_fast_reply(blocks) == h(EMANUAL_FAST_BULK_REPLY), "blocks of 4, 2 and 1 data bytes"
    assert split_fast_reply(decode_frame(h(EMANUAL_FAST_BULK_REPLY)), [4, 2, 1]) == blocks, "split back"


def test_fast_reply_with_a_bad_inner_crc_is_refused():
    raw = bytearray(h(EMANUAL_FAST_SYNC_REPLY))
    raw[14] ^= 0x01                                  # the first block's CRC, not the packet's
    raw[-2:] = pack_field(crc16(raw[:-2]), 2)       # so that the frame itself still checks
    with pytest.raises(CrcMismatch):
        split_fast_reply(decode_frame(bytes(raw)), [4, 4, 4])


def test_fast_reply_is_never_stuffed():
    # Present Current −1 then a byte FD: a normal status packet would stuff it, a fast reply must not
    block = FastReadBlock(1, 0, h("FF FF FD FD"))
    raw = encode_fast_reply([block])
    assert raw[5:7] == h("09 00") and len(raw) == 16, "LEN 9: INST, ERR, ID, 4 data, CRC; nothing added"
    assert raw[9:14] == h("01 FF FF FD FD"), "ID and data bytes go out as they are"
    packet = PacketReader().feed(raw)[0]
    assert split_fast_reply(packet, [4]) == [block], "the reader does not unstuff a reply from ID 0xFE"


def test_stuffing_inserts_fd_after_each_header_pattern():
    assert stuff(h("FF FF FD")) == h("FF FF FD FD"), "e-manual: FF FF FD → FF FF FD FD"
    assert stuff(h("FF FF FD FF FF FD 00")) == h("FF FF FD FD FF FF FD FD 00"), "every occurrence"
    assert stuff(h("FF FD FF FF")) == h("FF FD FF FF"), "no full pattern, nothing added"
    assert unstuff(h("FF FF FD FD FF FF FD FD 00")) == h("FF FF FD FF FF FD 00"), "the inverse"


def test_stuffing_round_trips_random_data():
    rng = random.Random(7)
    for _ in range(500):
        data = bytes(rng.choice(b"\xFF\xFD\x00") for _ in range(rng.randrange(40)))
        stuffed = stuff(data)
        assert unstuff(stuffed) == data, f"round trip of {data.hex(' ')}"
        assert len(stuffed) - len(data) == data.count(h("FF FF FD")), "one FD per pattern"


def test_status_with_present_current_minus_one_and_velocity_byte_fd():
    # read of 126..131: Present Current −1 (FF FF) then Present Velocity −3 (FD FF FF FF)
    data = pack_field(-1, 2, signed=True) + pack_field(-3, 4, signed=True)
    frame = StatusPacket(1, 0, data).encode()
    assert frame[:7] == h("FF FF FD 00 01 0B 00"), "LEN 11: INST, ERR, 6 data + 1 stuffed byte, CRC"
    assert frame[7:16] == h("55 00 FF FF FD FD FF FF FF"), "an FD inserted after FF FF FD"
    assert frame[-2:] == pack_field(crc16(frame[:-2]), 2), "CRC over the stuffed bytes"
    packet = decode_frame(frame)
    assert unpack_field(packet.params[:2], signed=True) == -1, "Present Current back to −1"
    assert unpack_field(packet.params[2:], signed=True) == -3, "Present Velocity back to −3"


def test_instruction_with_header_pattern_is_stuffed():
    frame = inst.write(1, 100, h("FF FF FD FD")).encode()     # Goal PWM −1, Goal Current −515
    assert frame[5:7] == h("0A 00"), "LEN 10 = INST + address(2) + 4 data + 1 stuffed + CRC"
    assert frame[7:15] == h("03 64 00 FF FF FD FD FD"), "stuffed parameters"
    assert decode_frame(frame).params == h("64 00 FF FF FD FD"), "unstuffed on decoding"


def test_fields_are_little_endian_and_range_checked():
    assert pack_field(-1, 2, signed=True) == h("FF FF"), "−1 in two's complement"
    assert pack_field(0x12345678, 4) == h("78 56 34 12"), "least significant byte first"
    assert unpack_field(h("FD FF FF FF"), signed=True) == -3, "signed 4-byte field"
    assert unpack_field(h("FF")) == 255, "unsigned 1-byte field"
    with pytest.raises(FieldRangeError):
        pack_field(256, 1)
    with pytest.raises(FieldRangeError):
        pack_field(1, 3)


def test_status_error_reports_number_and_alert():
    packet = decode_frame(StatusPacket(3, 0x87).encode())
    assert (packet.error_number, packet.alert) == (7, True), "ERR 0x87: access error with alert"
    with pytest.raises(StatusError) as caught:
        packet.raise_for_error()
    assert (caught.value.error_number, caught.value.servo_id) == (7, 3), "the exception carries both"


def test_parsers_invert_the_builders():
    packet = inst.bulk_write([(1, 116, pack_field(7, 4)), (2, 65, h("01"))])
    assert inst.parse_bulk_write(packet.params) == [(1, 116, pack_field(7, 4)), (2, 65, h("01"))], \
        "bulk write blocks come back in order"
    sync = inst.sync_write(116, 2, {4: h("01 02")})
    assert inst.parse_sync_write(sync.params) == (116, [(4, h("01 02"))]), "sync write: address, (id, data)"
    assert inst.parse_bulk_read(inst.bulk_read([(9, 132, 4)]).params) == [(9, 132, 4)], "bulk read block"
    with pytest.raises(BadParameters):
        inst.parse_sync_write(h("74 00 04 00 01 96 00"))            # a 4-byte block cut to 2
    with pytest.raises(BadParameters):
        inst.parse_read(h("84 00 04"))


# --- the frame reader ------------------------------------------------------------------------------

def packets_of(events):
    return [e for e in events if not isinstance(e, BadFrame)]


def faults_of(events):
    return [e.fault for e in events if isinstance(e, BadFrame)]


def test_reader_never_raises_on_garbage():
    rng = random.Random(1)
    reader = PacketReader()
    for _ in range(2000):
        chunk = bytes(rng.choice(b"\xFF\xFD\x00\x01\x55") for _ in range(rng.randrange(30)))
        events = reader.feed(chunk)
        assert all(isinstance(e, (BadFrame, InstructionPacket, StatusPacket)) for e in events), \
            "only packets and fault events come out"
        assert reader.pending <= 1024, "never holds more than one maximal frame"


def test_reader_finds_packets_between_garbage_in_any_chunking():
    rng = random.Random(2)
    packets = [inst.ping(1), inst.write(2, 100, h("FF FF FD FD")), StatusPacket(1, 0, h("FF FF FD 00")),
               inst.sync_read(132, 4, [1, 2, 3]), StatusPacket(4, 0x80)]
    stream = bytearray()
    for packet in packets:
        # garbage without FF cannot fake a header, so every packet must come back
        stream += bytes(rng.choice(b"\x00\x01\xFD\x55\x80") for _ in range(rng.randrange(12)))
        stream += packet.encode()
    for trial in range(50):
        reader, events, k = PacketReader(), [], 0
        while k < len(stream):
            n = 1 if trial == 0 else rng.randrange(1, 9)       # byte by byte, then random chunks
            events += reader.feed(bytes(stream[k:k + n]))
            k += n
        assert packets_of(events) == packets, f"trial {trial}: all five packets, in order"
        assert set(faults_of(events)) <= {Fault.GARBAGE}, "nothing but the garbage is reported"


def test_reader_reports_a_bad_crc_and_goes_on():
    bad = bytearray(inst.write(1, 116, pack_field(512, 4)).encode())
    bad[10] ^= 0x40                                              # one data bit flipped
    events = PacketReader().feed(bytes(bad) + inst.ping(2).encode())
    assert isinstance(events[0], BadFrame) and events[0].fault is Fault.CRC, "the corrupted write"
    assert (events[0].id, events[0].instruction) == (1, 0x03), "its ID and instruction are readable"
    assert packets_of(events) == [inst.ping(2)], "the next packet still arrives"


def test_reader_recovers_a_packet_sent_inside_a_truncated_one():
    truncated = inst.read(1, 132, 4).encode()[:8]               # LEN promises 14 bytes
    events = PacketReader().feed(truncated + inst.ping(3).encode() + bytes(4))
    assert faults_of(events)[0] is Fault.CRC, "the cut packet swallows bytes and fails its CRC"
    assert packets_of(events) == [inst.ping(3)], "the ping inside it is found by searching again"


def test_reader_holds_a_partial_packet_until_expired():
    reader = PacketReader()
    assert reader.feed(inst.ping(1).encode()[:6]) == [], "nothing complete yet"
    assert reader.pending == 6, "the partial frame is kept"
    events = reader.expire()
    assert [e.fault for e in events] == [Fault.TRUNCATED] and reader.pending == 0, "dropped on expiry"


def test_reader_drops_a_partial_packet_after_the_byte_timeout():
    frame = inst.ping(1).encode()
    reader = PacketReader()
    assert reader.feed(frame[:5], now=0.0) == [], "5 of 10 bytes: nothing yet"
    assert packets_of(reader.feed(frame[5:], now=0.001)) == [inst.ping(1)], "1 ms gap: one packet"
    reader.feed(frame[:5], now=1.0)
    events = reader.feed(frame[5:], now=1.002)                   # 2 ms > 1.5 ms
    assert faults_of(events) == [Fault.TRUNCATED, Fault.GARBAGE], "head abandoned, tail is garbage"


@pytest.mark.parametrize("head, reason", [
    ("FF FF FD 00 01 02 00", "LEN 2 < 3"),
    ("FF FF FD 00 FF 03 00", "ID 0xFF does not exist"),
    ("FF FF FD 00 01 FF FF", "LEN 65535 exceeds the largest frame"),
])
def test_reader_rejects_impossible_headers_at_once(head, reason):
    reader = PacketReader()
    events = reader.feed(h(head) + inst.ping(5).encode())
    assert faults_of(events)[0] is Fault.HEADER, reason
    assert packets_of(events) == [inst.ping(5)], f"{reason}: the following ping is not lost"
    assert reader.pending == 0, "nothing is held back waiting for a frame that cannot come"


def test_broadcast_status_is_only_a_fast_reply():
    assert StatusPacket(BROADCAST_ID, 0, h("01 FF FF FD 00")).encode()[5:7] == h("09 00"), \
        "LEN 9, not 10: a status packet from 0xFE is sent unstuffed"
    assert StatusPacket(1, 0, h("01 FF FF FD 00")).encode()[5:7] == h("0A 00"), "from ID 1 it is stuffed"
