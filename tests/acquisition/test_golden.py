"""Every golden telegram of shared/docs/protocols.md, byte for byte."""

import numpy as np
import pytest

from rangeseg_o3d.acquisition.errors import LmsProtocolError, PowerCubeProtocolError
from rangeseg_o3d.acquisition.lms2xx import crc16, decode_telegram, encode_telegram, parse_scan
from rangeseg_o3d.acquisition.powercube import FROM_MODULE, decode_frame, encode_frame, pack_float, unpack_float

LMS_REQUESTS = [
    ("20 24", "02 00 02 00 20 24 34 08"),
    ("20 25", "02 00 02 00 20 25 35 08"),
    ("20 40", "02 00 02 00 20 40 50 08"),
    ("20 41", "02 00 02 00 20 41 51 08"),
    ("20 42", "02 00 02 00 20 42 52 08"),
    ("20 48", "02 00 02 00 20 48 58 08"),
    ("30 01", "02 00 02 00 30 01 31 18"),
    ("31", "02 00 01 00 31 15 12"),
    ("3A", "02 00 01 00 3A 1E 12"),
    ("74", "02 00 01 00 74 50 12"),
    ("20 00 53 49 43 4B 5F 4C 4D 53", "02 00 0A 00 20 00 53 49 43 4B 5F 4C 4D 53 BE C5"),
    ("3B B4 00 64 00", "02 00 05 00 3B B4 00 64 00 97 49"),
    ("3B B4 00 32 00", "02 00 05 00 3B B4 00 32 00 3B 1F"),
    ("3B 64 00 64 00", "02 00 05 00 3B 64 00 64 00 1D 0F"),
    ("3B 64 00 19 00", "02 00 05 00 3B 64 00 19 00 E7 72"),
]
LMS_REPLIES = [
    (0x80, "A0 00 10", "02 80 03 00 A0 00 10 16 0A"),
    (0x81, "A0 00 10", "02 81 03 00 A0 00 10 36 1A"),
    (0x80, "91 10", "02 80 02 00 91 10 79 30"),
    (0x80, "B0 03 40 E8 03 FF 1F F7 1F 10", "02 80 0A 00 B0 03 40 E8 03 FF 1F F7 1F 10 03 3B"),
]


@pytest.mark.parametrize("payload, wire", LMS_REQUESTS)
def test_lms_request_encoding(payload, wire):
    assert encode_telegram(bytes.fromhex(payload)) == bytes.fromhex(wire)
    t = decode_telegram(bytes.fromhex(wire))
    assert bytes([t.command]) + t.data == bytes.fromhex(payload) and t.status is None


@pytest.mark.parametrize("address, payload, wire", LMS_REPLIES)
def test_lms_reply_encoding(address, payload, wire):
    assert encode_telegram(bytes.fromhex(payload), address) == bytes.fromhex(wire)
    t = decode_telegram(bytes.fromhex(wire))
    assert t.address == address and t.status == 0x10 and t.is_reply


def test_crc_wire_order_low_byte_first():
    assert crc16(bytes.fromhex("02 00 02 00 20 24")) == 0x0834


def test_constructed_scan_values():
    t = decode_telegram(bytes.fromhex("02 80 0A 00 B0 03 40 E8 03 FF 1F F7 1F 10 03 3B"))
    scan = parse_scan(t, expected_count=3, expected_unit=0.001)
    assert scan.ranges[0] == pytest.approx(1.0)
    assert np.isnan(scan.ranges[1:]).all()  # 0x1FFF no return, 0x1FF7 too far
    assert scan.raw.tolist() == [1000, 0x1FFF, 0x1FF7] and scan.status == 0x10


def test_full_scan_header():
    from rangeseg_o3d.acquisition.lms2xx import encode_scan_values

    frame = encode_telegram(encode_scan_values(np.full(181, 2.0)), 0x80)
    assert len(frame) == 372 and frame[:7] == bytes.fromhex("02 80 6E 01 B0 B5 40")


def test_lms_corrupted_crc_rejected():
    wire = bytearray(bytes.fromhex("02 00 02 00 30 01 31 18"))
    wire[-1] ^= 1
    with pytest.raises(LmsProtocolError, match="CRC"):
        decode_telegram(bytes(wire))


POWERCUBE = [
    ("0A 3C", "02 05 62 0A 3C AD 03"),
    ("0A 27", "02 05 62 0A 27 98 03"),
    ("00", "02 05 61 00 66 03"),
    ("01", "02 05 61 01 67 03"),
    ("02", "02 05 61 10 82 68 03"),  # 0x02 escaped
    ("08 4F " + pack_float(0.5).hex(), "02 05 66 08 4F 00 00 00 3F 10 82 03"),  # BCC 0x02 escaped
    ("0B 04 " + pack_float(0.3).hex(), "02 05 66 0B 04 9A 99 99 3E 86 03"),
    ("0B 04 " + pack_float(-0.4).hex(), "02 05 66 0B 04 CD CC CC BE A0 03"),
]


@pytest.mark.parametrize("data, wire", POWERCUBE)
def test_powercube_frames(data, wire):
    assert encode_frame(11, bytes.fromhex(data)) == bytes.fromhex(wire)
    frame = decode_frame(bytes.fromhex(wire))
    assert (frame.module_id, frame.data) == (11, bytes.fromhex(data))


def test_powercube_position_reply():
    wire = bytes.fromhex("02 09 66 0A 3C 9A 99 99 3E C1 03")
    assert encode_frame(11, bytes.fromhex("0A 3C") + pack_float(0.3), direction=FROM_MODULE) == wire
    frame = decode_frame(wire)
    assert frame.direction == FROM_MODULE and unpack_float(frame.data[2:]) == pytest.approx(0.3, abs=1e-7)


def test_powercube_bad_bcc_and_escape():
    with pytest.raises(PowerCubeProtocolError, match="BCC"):
        decode_frame(bytes.fromhex("02 05 62 0A 3C AE 03"))
    assert decode_frame(bytes.fromhex("02 05 62 0A 3C AE 03"), check_bcc=False).data == b"\x0a\x3c"
    with pytest.raises(PowerCubeProtocolError, match="escape"):
        decode_frame(bytes.fromhex("02 05 61 10 41 68 03"))
