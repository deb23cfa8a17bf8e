import numpy as np
import pytest

from rangeseg_o3d.io.lzf import lzf_compress, lzf_decompress


@pytest.mark.parametrize(
    "payload",
    [
        b"",
        b"a",
        b"ab",
        bytes(range(256)) * 3,
        b"\x00" * 10_000,  # long runs: overlapping back-references, 264-byte max length
        np.random.default_rng(0).bytes(3000),  # incompressible: literal runs only
        np.full(2000, np.nan, np.float32).tobytes() + np.arange(500, dtype=np.float32).tobytes(),
    ],
)
def test_round_trip(payload):
    packed = lzf_compress(payload)
    assert lzf_decompress(packed, len(payload)) == payload


def test_hand_built_stream():
    # literal "abc", back-reference of length 3 at distance 3, overlapping ref of length 9+1 at distance 1
    stream = bytes([2]) + b"abc" + bytes([0x20, 0x02]) + bytes([0xE0, 0x01, 0x00])
    assert lzf_decompress(stream, 6 + 10) == b"abcabc" + b"c" * 10


def test_incompressible_payload_stays_within_the_worst_case_bound():
    payload = np.random.default_rng(1).bytes(100_000)
    packed = lzf_compress(payload)
    assert len(packed) <= len(payload) + len(payload) // 32 + 16
    assert lzf_decompress(packed, len(payload)) == payload


def test_long_reference_uses_extra_length_byte():
    payload = b"xy" * 300
    compressed = lzf_compress(payload)
    assert len(compressed) < 20
    assert lzf_decompress(compressed, len(payload)) == payload


def test_negative_length_refused():
    with pytest.raises(ValueError, match="out_len must be >= 0"):
        lzf_decompress(b"", -1)


@pytest.mark.parametrize(
    "stream, out_len, message",
    [
        (bytes([5]) + b"abc", 6, "truncated"),
        (bytes([0x20]), 3, "truncated"),
        (bytes([0x20, 0x05]), 3, "before the start|corrupt"),
        (bytes([2]) + b"abc", 5, "decompresses to 3 bytes but 5"),
        (bytes([2]) + b"abc", 2, "3 bytes but 2|more than the declared 2"),
        (bytes([2]) + b"abc" + bytes([0xE0, 0xFF, 0x00]), 3, "but 3|more than the declared 3"),
    ],
)
def test_corrupt_streams_raise(stream, out_len, message):
    with pytest.raises(ValueError, match=message):
        lzf_decompress(stream, out_len)
