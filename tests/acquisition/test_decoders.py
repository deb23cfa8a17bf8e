"""Stream decoders: resynchronisation, split feeds, round trips; a 100,000-frame fuzz run."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rangeseg_o3d.acquisition.errors import LmsProtocolError, PowerCubeProtocolError, ProtocolError
from rangeseg_o3d.acquisition.lms2xx import (
    Ack,
    BadFrame,
    Nak,
    Telegram,
    TelegramDecoder,
    decode_telegram,
    encode_scan_values,
    encode_telegram,
    parse_scan,
)
from rangeseg_o3d.acquisition.powercube import FrameDecoder, decode_frame, encode_frame


def test_lms_stream_resynchronises_on_garbage_and_split_feeds():
    a = encode_telegram(b"\xa0\x00\x10", 0x80)
    b = encode_telegram(encode_scan_values(np.array([1.0, 2.0])), 0x80)
    stream = b"\x06\x55\x02\x80" + a + b"\x00\x02\xff" + b + b"\x15"
    decoder = TelegramDecoder()
    events = []
    for k in range(0, len(stream), 3):
        decoder.feed(stream[k : k + 3])
        events += decoder.events()
    telegrams = [e for e in events if isinstance(e, Telegram)]
    assert [t.command for t in telegrams] == [0xA0, 0xB0]
    assert any(isinstance(e, Ack) for e in events) and isinstance(events[-1], Nak)
    assert not decoder.pending


def test_bad_crc_reported_and_data_bytes_not_taken_for_handshakes():
    frame = bytearray(encode_telegram(b"\xba\x06\x15\x06", 0x80))
    frame[-1] ^= 0x40
    decoder = TelegramDecoder()
    decoder.feed(bytes(frame))
    events = decoder.events()
    assert [type(e) for e in events] == [BadFrame]


def test_request_decoder_ignores_replies():
    decoder = TelegramDecoder(replies=False)
    decoder.feed(encode_telegram(b"\xa0\x00\x10", 0x80) + encode_telegram(b"\x30\x01"))
    assert [(e.command, e.data) for e in decoder.events()] == [(0x30, b"\x01")]


@pytest.mark.parametrize("mutate, match", [
    (lambda d: d[:4] + d[5:], "length"),
    (lambda d: d[:3], "at least 7"),
    (lambda d: b"\x03" + d[1:], "STX"),
    (lambda d: d[:-1], "length"),
])
def test_decode_telegram_errors(mutate, match):
    wire = encode_telegram(b"\x30\x01")
    with pytest.raises(LmsProtocolError, match=match):
        decode_telegram(mutate(wire))


def test_parse_scan_checks():
    good = decode_telegram(encode_telegram(encode_scan_values(np.ones(4)), 0x80))
    assert parse_scan(good, expected_count=4, expected_unit=0.001).ranges.tolist() == [1.0] * 4
    with pytest.raises(LmsProtocolError, match="expected 5"):
        parse_scan(good, expected_count=5)
    with pytest.raises(LmsProtocolError, match="unit"):
        parse_scan(good, expected_unit=0.01)
    lying = Telegram(0x80, 0xB0, good.data[:-2], 0x10)  # count says 4, 3 values present
    with pytest.raises(LmsProtocolError, match="announces 4"):
        parse_scan(lying)
    with pytest.raises(LmsProtocolError, match="error"):
        parse_scan(Telegram(0x80, 0xB0, good.data, 0x13))
    with pytest.raises(LmsProtocolError, match="0xB0"):
        parse_scan(Telegram(0x80, 0xBA, good.data, 0x10))
    with pytest.raises(TypeError):
        parse_scan(b"\xb0")


def test_count_word_bits():
    data = bytes([0x02, 0x40 | 0x20 | 0x08]) + bytes.fromhex("e803 0120")  # partial flag, offset bits
    scan = parse_scan(Telegram(0x80, 0xB0, data, 0x10))
    assert scan.partial and scan.ranges[0] == 1.0 and scan.ranges[1] == pytest.approx(1.0 * 0.001)
    assert scan.flags.tolist() == [0, 1]  # bit 13 of the second word: field A


def test_encode_bad_inputs():
    with pytest.raises(ValueError, match="payload"):
        encode_telegram(b"")
    with pytest.raises(TypeError):
        encode_telegram("30 01")
    with pytest.raises(ValueError, match="module_id"):
        encode_frame(0, b"\x00")
    with pytest.raises(ValueError, match="1..8"):
        encode_frame(11, bytes(9))


@settings(max_examples=200, deadline=None)
@given(payload=st.binary(min_size=2, max_size=60), address=st.sampled_from([0x80, 0x81]))
def test_lms_round_trip(payload, address):
    t = decode_telegram(encode_telegram(payload, address))
    assert bytes([t.command]) + t.data + bytes([t.status]) == payload


@settings(max_examples=200, deadline=None)
@given(data=st.binary(min_size=1, max_size=8), module=st.integers(1, 31))
def test_powercube_round_trip_with_escaping(data, module):
    wire = encode_frame(module, data)
    assert wire.count(0x02) == 1 and wire.count(0x03) == 1  # escaping leaves one STX and one ETX
    frame = decode_frame(wire)
    assert (frame.module_id, frame.data) == (module, data)
    decoder = FrameDecoder()
    decoder.feed(b"\x03\x10" + wire[:4])
    decoder.feed(wire[4:])
    assert [(f.module_id, f.data) for f in decoder.frames()] == [(module, data)]


def _mutations(rng, seeds, n):
    """``n`` frames: valid ones mutated (flips, drops, insertions, truncation, splices) or random bytes."""
    for k in range(n):
        kind = k % 6
        base = bytearray(seeds[rng.integers(len(seeds))])
        if kind == 0:
            yield rng.integers(0, 256, rng.integers(0, 40), dtype=np.uint8).tobytes()
            continue
        if kind == 1 and base:
            base[rng.integers(len(base))] ^= int(rng.integers(1, 256))
        elif kind == 2 and base:
            del base[rng.integers(len(base))]
        elif kind == 3:
            base.insert(int(rng.integers(len(base) + 1)), int(rng.integers(256)))
        elif kind == 4:
            base = base[: rng.integers(len(base) + 1)]
        else:
            other = seeds[rng.integers(len(seeds))]
            base = base[: rng.integers(len(base) + 1)] + other[rng.integers(len(other) + 1):]
        yield bytes(base)


def test_fuzz_100k_frames_only_protocol_errors_escape():
    rng = np.random.default_rng(12345)
    lms_seeds = [encode_telegram(bytes(rng.integers(0, 256, rng.integers(1, 12), dtype=np.uint8)), a)
                 for a in (0, 0x80) for _ in range(20)]
    lms_seeds += [encode_telegram(encode_scan_values(rng.uniform(0, 9, n)), 0x80) for n in (1, 3, 7)]
    lms_seeds += [encode_telegram(bytes([0xB0]) + bytes(rng.integers(0, 256, 9, dtype=np.uint8)), 0x80)]
    pc_seeds = [encode_frame(int(rng.integers(1, 32)), bytes(rng.integers(0, 256, rng.integers(1, 9), dtype=np.uint8)))
                for _ in range(40)]
    stream_lms, stream_pc = TelegramDecoder(), FrameDecoder()
    fed = accepted = 0
    for frame in _mutations(rng, lms_seeds, 60_000):
        fed += 1
        try:
            t = decode_telegram(frame)
            accepted += 1
            if t.is_reply:
                parse_scan(t, expected_count=None)
        except ProtocolError:
            pass
        stream_lms.feed(frame)
        for event in stream_lms.events():
            if isinstance(event, Telegram) and event.is_reply:
                try:
                    parse_scan(event)
                except LmsProtocolError:
                    pass
    for frame in _mutations(rng, pc_seeds, 40_000):
        fed += 1
        try:
            decode_frame(frame)
        except PowerCubeProtocolError:
            pass
        stream_pc.feed(frame)
        for item in stream_pc.frames():
            assert isinstance(item, PowerCubeProtocolError) or 1 <= len(item.data) <= 8
    assert fed == 100_000
    assert 0 < accepted < 60_000
