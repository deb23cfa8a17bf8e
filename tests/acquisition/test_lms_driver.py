"""One scripted exchange per LMS2xx command, plus NAK, corruption, reset and silence handling."""

import time

import numpy as np
import pytest

from rangeseg_o3d.acquisition import lms_driver
from rangeseg_o3d.acquisition.errors import SILENT_REQUESTS, DeviceTimeout, LmsDeviceReset, LmsProtocolError
from rangeseg_o3d.acquisition.lms2xx import encode_scan_values, encode_telegram
from rangeseg_o3d.acquisition.lms_driver import Lms2xx

from acquisition_helpers import raises_without_hanging

ACK, NAK = b"\x06", b"\x15"


def req(hexstr):
    return encode_telegram(bytes.fromhex(hexstr))


def rep(hexstr, status=0x10):
    return encode_telegram(bytes.fromhex(hexstr) + bytes([status]), 0x80)


def make(scripted, script, **kw):
    transport = scripted(script, **{k: kw.pop(k) for k in ("baudrate",) if k in kw})
    return transport, Lms2xx(transport, timeout=kw.pop("timeout", 0.3), reply_timeout=kw.pop("reply_timeout", 0.1),
                             gap_timeout=0.01, settle=0.0, **kw)


def test_mode_change_golden_reply(scripted):
    _, lms = make(scripted, [(bytes.fromhex("02 00 02 00 20 25 35 08"),
                              ACK + bytes.fromhex("02 81 03 00 A0 00 10 36 1A"))])
    lms.set_mode(0x25)


def test_installation_mode_sends_password(scripted):
    wire = bytes.fromhex("02 00 0A 00 20 00 53 49 43 4B 5F 4C 4D 53 BE C5")
    _, lms = make(scripted, [(wire, ACK + rep("A0 00"))])
    lms.set_mode(0x00)


def test_refused_mode_raises(scripted):
    _, lms = make(scripted, [(req("20 24"), ACK + rep("A0 01"))])
    with pytest.raises(LmsProtocolError, match="refused"):
        lms.set_mode(0x24)


def test_device_type_and_status(scripted):
    _, lms = make(scripted, [(req("3A"), ACK + rep("BA" + b"LMS200;30106".hex())),
                             (req("31"), ACK + rep("B1 01 02"))])
    assert lms.device_type() == "LMS200;30106"
    assert lms.status().data == b"\x01\x02"


def test_variant(scripted):
    _, lms = make(scripted, [(bytes.fromhex("02 00 05 00 3B 64 00 19 00 E7 72"), ACK + rep("BB 01 64 00 19 00"))])
    assert lms.set_variant(100, 25) == 401 and lms.n_values == 401


def test_variant_rejected(scripted):
    _, lms = make(scripted, [(req("3B B4 00 32 00"), ACK + rep("BB 00 B4 00 32 00"))])
    with pytest.raises(LmsProtocolError, match="rejected"):
        lms.set_variant(180, 50)


def test_impossible_variant_is_value_error(scripted):
    _, lms = make(scripted, [])
    with pytest.raises(ValueError, match="fov, resolution"):
        lms.set_variant(180, 25)


def test_units_read_modify_write(scripted):
    cfg = bytes(34)
    new = bytearray(cfg)
    new[6] = 1
    _, lms = make(scripted, [
        (req("74"), ACK + rep("F4" + cfg.hex())),
        (req("20 00 53 49 43 4B 5F 4C 4D 53"), ACK + rep("A0 00")),
        (req("77" + new.hex()), ACK + rep("F7 01" + new.hex())),
        (req("20 25"), ACK + rep("A0 00")),
    ])
    lms.set_units("mm")
    assert lms.unit == 0.001


def test_units_already_set_only_reads(scripted):
    cfg = bytearray(32)
    cfg[6] = 1
    _, lms = make(scripted, [(req("74"), ACK + rep("F4" + cfg.hex()))])
    lms.set_units("mm")


def test_baud_switch_reply_at_old_rate_then_verify(scripted):
    transport, lms = make(scripted, [(bytes.fromhex("02 00 02 00 20 48 58 08"), ACK + rep("A0 00")),
                                     (req("3A"), ACK + rep("BA 4C 4D 53"))])
    lms.set_baudrate(500000)
    assert transport.baud_at_write == [9600, 500000] and transport.baudrate == 500000


def test_baud_detection_probes_until_an_answer(scripted):
    probe = bytes.fromhex("02 00 02 00 20 25 35 08")
    transport, lms = make(scripted, [(probe, b""), (probe, b""), (probe, b""), (probe, b""),
                                     (probe, ACK + rep("A0 00"))])
    assert lms.detect_baudrate(reply_timeout=0.02) == 38400
    assert transport.baud_at_write == [9600, 9600, 19200, 19200, 38400]


def test_baud_detection_silent_device(scripted):
    probe = req("20 25")
    # 4 rates x 2 probes, swept 3 times (a probe garbled on a noisy line is not a silent device)
    _, lms = make(scripted, [(probe, b"")] * 24)
    with pytest.raises(DeviceTimeout, match="scripted"):
        lms.detect_baudrate(reply_timeout=0.01)


def test_request_one_scan(scripted):
    ranges = np.array([1.0, 2.5, np.nan])
    _, lms = make(scripted, [(bytes.fromhex("02 00 02 00 30 01 31 18"),
                              ACK + encode_telegram(encode_scan_values(ranges), 0x80))])
    lms.n_values, lms.unit = 3, 0.001
    scan = lms.request_scan()
    np.testing.assert_allclose(scan.ranges, ranges)


def test_a_reply_owed_to_an_earlier_send_is_not_taken_for_the_next_scan(scripted):
    # The first scan's send 1 goes unanswered in time and send 2 gets send 1's late answer (scan 1);
    # send 2's own answer (scan 2) comes only with the next request, which may follow a tilt move. So
    # the next scan first settles the line (3A, device type): what comes before its BA was owed.
    one, two, three = (encode_telegram(encode_scan_values(np.full(3, v)), 0x80) for v in (1.0, 2.0, 3.0))
    _, lms = make(scripted, [(req("30 01"), b""), (req("30 01"), ACK + one),
                             (req("3A"), ACK + two + ACK + rep("BA 41")),
                             (req("30 01"), ACK + three), (req("30 01"), ACK + one)], reply_timeout=0.02)
    lms.n_values, lms.unit = 3, 0.001
    assert lms.request_scan().ranges[0] == 1.0
    assert lms.request_scan().ranges[0] == 3.0
    assert lms.request_scan().ranges[0] == 1.0  # answered at the first send: nothing owed, no 3A
    assert lms.stats["settled"] == 1 and lms.stats["silent"] == 1


def test_a_failed_scan_request_settles_the_line_before_the_next(scripted):
    # discard_stale's single try fails (its answer may still come): the next scan is not its answer
    one, two = (encode_telegram(encode_scan_values(np.full(3, v)), 0x80) for v in (1.0, 2.0))
    _, lms = make(scripted, [(req("30 01"), ACK), (req("3A"), one + ACK + rep("BA 41")),
                             (req("30 01"), ACK + two)], reply_timeout=0.02)
    lms.n_values, lms.unit = 3, 0.001
    with pytest.raises(LmsProtocolError):
        lms.request_scan(attempts=1)
    assert lms.request_scan().ranges[0] == 2.0


def test_nak_waits_at_least_30ms_then_resends(scripted, monkeypatch):
    pauses = []
    monkeypatch.setattr(lms_driver, "sleep", pauses.append)
    _, lms = make(scripted, [(req("31"), NAK), (req("31"), ACK + rep("B1 00"))])
    lms.status()
    assert pauses == [pytest.approx(0.03)] and lms.stats["nak"] == 1


def test_corrupted_reply_is_resent_and_garbage_skipped(scripted):
    good = rep("BA 41")
    bad = bytearray(good)
    bad[5] ^= 0xFF
    _, lms = make(scripted, [(req("3A"), ACK + bytes(bad)), (req("3A"), b"\x00\x7f\x02\x99" + ACK + good)])
    assert lms.device_type() == "A"
    assert lms.stats["bad_frames"] == 1


def test_truncated_reply_abandoned_after_gap(scripted):
    good = rep("BA 41")
    _, lms = make(scripted, [(req("3A"), ACK + good[:-3]), (req("3A"), ACK + good)])
    assert lms.device_type() == "A" and lms.stats["broken"] == 1


def test_power_on_telegram_raises_reset(scripted):
    _, lms = make(scripted, [(req("30 01"), rep("90 4C 4D 53"))])
    with pytest.raises(LmsDeviceReset):
        lms.request_scan()


def test_wrong_count_never_accepted(scripted):
    short = encode_telegram(encode_scan_values(np.ones(5)), 0x80)
    _, lms = make(scripted, [(req("30 01"), ACK + short)] * 2)
    lms.n_values, lms.unit = 181, 0.001
    with pytest.raises(LmsProtocolError, match="consistent scan"):
        lms.request_scan(attempts=2)


def test_wrong_unit_never_accepted(scripted):
    cm = encode_telegram(encode_scan_values(np.ones(3), unit=0.01), 0x80)
    _, lms = make(scripted, [(req("30 01"), ACK + cm)])
    lms.n_values, lms.unit = 3, 0.001
    with pytest.raises(LmsProtocolError):
        lms.request_scan(attempts=1)


def test_silent_device_times_out_naming_the_port(scripted):
    _, lms = make(scripted, [(req("31"), b"")] * SILENT_REQUESTS, timeout=0.05, reply_timeout=0.02)
    with pytest.raises(DeviceTimeout, match="scripted") as info:
        lms.status()
    assert info.value.port == "scripted"
    assert lms.stats["silent"] == SILENT_REQUESTS


def test_a_few_unanswered_requests_are_not_a_dead_device(scripted):
    # requests garbled on the line go unanswered; past `timeout` of silence, fewer than
    # SILENT_REQUESTS of them in a row are still resent
    script = [(req("31"), b"")] * (SILENT_REQUESTS - 1) + [(req("31"), ACK + rep("B1 00"))]
    _, lms = make(scripted, script, timeout=0.01, reply_timeout=0.02)
    assert lms.status().data == b"\x00"
    assert lms.stats["silent"] == SILENT_REQUESTS - 1


def test_a_whole_frame_failing_its_crc_is_resent_at_once(scripted):
    bad = bytearray(rep("B1 00"))
    bad[-1] ^= 0xFF  # CRC wrong, frame complete
    transport = scripted([(req("31"), ACK + bytes(bad)), (req("31"), ACK + rep("B1 00"))])
    lms = Lms2xx(transport, timeout=10.0, reply_timeout=5.0, gap_timeout=5.0, settle=0.0)
    start = time.monotonic()
    assert lms.status().data == b"\x00"
    assert time.monotonic() - start < 2.0  # not the 5 s gap or reply timeout
    assert lms.stats["bad_frames"] == 1 and lms.stats["broken"] == 1


def test_rejection_0x92(scripted):
    _, lms = make(scripted, [(req("30 01"), ACK + rep("92 30"))])
    with pytest.raises(LmsProtocolError, match="rejected"):
        lms.request_scan()


def test_streaming(scripted):
    scans = b"".join(encode_telegram(encode_scan_values(np.full(2, r)), 0x80) for r in (1.0, 2.0))
    _, lms = make(scripted, [(req("20 24"), ACK + rep("A0 00") + scans), (req("20 25"), ACK + rep("A0 00"))])
    lms.n_values, lms.unit = 2, 0.001
    lms.start_streaming()
    # the mode reply and the first scans arrived together: the scans are kept for read_streamed
    first, _ = lms.read_streamed(0.05)
    second, _ = lms.read_streamed(0.05)
    assert first.ranges.tolist() == [1.0, 1.0] and second.ranges.tolist() == [2.0, 2.0]
    assert lms.read_streamed(0.01) is None
    lms.stop_streaming()


def test_scans_arriving_apart_keep_their_arrival_times_when_taken_late(scripted):
    transport, lms = make(scripted, [(req("20 24"), ACK + rep("A0 00")), (req("20 25"), ACK + rep("A0 00"))])
    lms.n_values, lms.unit = 2, 0.001
    lms.start_streaming()
    arrived = []
    for r in (1.0, 2.0):
        arrived.append(time.monotonic())
        transport._rx += encode_telegram(encode_scan_values(np.full(2, r)), 0x80)
        time.sleep(0.1)
    scans = lms.drain_streamed()  # 0.1 s after the last arrival: a host that was busy elsewhere
    assert [scan.ranges[0] for scan, _ in scans] == [1.0, 2.0]
    stamps = np.array([stamp for _, stamp in scans])
    # read by the driver's thread as they came (its wait is gap_timeout = 10 ms), not when taken
    assert np.all(stamps - arrived >= 0) and np.all(stamps - arrived < 0.05), stamps - arrived
    lms.stop_streaming()
    assert lms.drain_streamed() == [] and lms.read_streamed(0.01) is None


def test_scan_in_flight_when_streaming_stops_is_kept(scripted):
    in_flight = encode_telegram(encode_scan_values(np.full(2, 3.0)), 0x80)
    _, lms = make(scripted, [(req("20 24"), ACK + rep("A0 00")), (req("20 25"), in_flight + ACK + rep("A0 00"))])
    lms.n_values, lms.unit = 2, 0.001
    lms.start_streaming()
    assert lms.drain_streamed() == []
    lms.stop_streaming()
    (scan, _), = lms.drain_streamed()
    assert scan.ranges.tolist() == [3.0, 3.0]


def scan_frame(r):
    return encode_telegram(encode_scan_values(np.full(2, r)), 0x80)


def test_a_damaged_scan_while_stopping_the_stream_is_no_reason_to_resend(scripted):
    damaged = bytearray(scan_frame(4.0))
    damaged[7] ^= 0x40  # one range byte hit on the line: the frame fails its CRC
    stop_reply = bytes(damaged) + scan_frame(5.0) + ACK + rep("A0 00")
    transport, lms = make(scripted, [(req("20 24"), ACK + rep("A0 00")), (req("20 25"), stop_reply)])
    lms.n_values, lms.unit = 2, 0.001
    lms.start_streaming()
    lms.stop_streaming()  # one 20 25: the damaged scan is neither a NAK nor a reply
    assert [scan.ranges[0] for scan, _ in lms.drain_streamed()] == [5.0]
    assert len(transport.writes) == 2 and lms.stats["broken"] == 0


def test_a_resend_while_stopping_the_stream_keeps_the_scan_in_flight(scripted):
    in_flight = scan_frame(6.0)
    transport, lms = make(scripted, [(req("20 24"), ACK + rep("A0 00")),
                                     (req("20 25"), NAK + in_flight[:5]),  # request garbled: NAK, stream goes on
                                     (req("20 25"), in_flight[5:] + ACK + rep("A0 00"))])
    lms.n_values, lms.unit = 2, 0.001
    lms.start_streaming()
    lms.stop_streaming()
    assert [scan.ranges[0] for scan, _ in lms.drain_streamed()] == [6.0]
    assert lms.stats["nak"] == 1


def test_streamed_scans_damaged_on_the_line_are_counted_and_the_others_kept(scripted):
    crc_hit = bytearray(scan_frame(2.0))
    crc_hit[8] ^= 0x01
    wrong_count = encode_telegram(encode_scan_values(np.full(3, 3.0)), 0x80)  # whole, but not this variant
    transport, lms = make(scripted, [(req("20 24"), ACK + rep("A0 00") + scan_frame(1.0)),
                                     (req("20 25"), bytes(crc_hit) + ACK + rep("A0 00"))])
    lms.n_values, lms.unit = 2, 0.001
    lms.start_streaming()
    transport._rx += bytes(crc_hit) + scan_frame(4.0) + wrong_count + scan_frame(5.0)
    time.sleep(0.1)
    lms.stop_streaming()
    assert [scan.ranges[0] for scan, _ in lms.drain_streamed()] == [1.0, 4.0, 5.0]
    # one damaged while streaming, one while stopping, one inconsistent; no request resent
    assert lms.stats["damaged_scans"] == 3 and lms.stats["bad_frames"] == 0 and len(transport.writes) == 2


def test_reset_while_streaming_raises(scripted):
    power_on = encode_telegram(b"\x90" + b"LMS200;30106" + b"\x10", 0x80)
    transport, lms = make(scripted, [(req("20 24"), ACK + rep("A0 00"))])
    lms.n_values, lms.unit = 2, 0.001
    lms.start_streaming()
    transport._rx += power_on
    with pytest.raises(LmsDeviceReset, match="while streaming"):
        lms.read_streamed(0.5)
    lms.close()


def test_valid_scans_taken_with_a_power_on_telegram_are_kept(scripted):
    def scan(r):
        return encode_telegram(encode_scan_values(np.full(2, r)), 0x80)

    power_on = encode_telegram(b"\x90" + b"LMS200;30106" + b"\x10", 0x80)
    transport, lms = make(scripted, [(req("20 24"), ACK + rep("A0 00"))])
    lms.n_values, lms.unit = 2, 0.001
    lms.start_streaming()
    transport._rx += scan(1.0) + power_on + scan(2.0) + scan(3.0)  # one chunk for the reader thread
    time.sleep(0.1)
    with pytest.raises(LmsDeviceReset, match="while streaming"):
        lms.drain_streamed()
    assert [scan.ranges[0] for scan, _ in lms.drain_streamed()] == [1.0, 2.0, 3.0]
    assert lms.stats["resets"] == 1
    lms.close()


def test_a_reset_in_the_reply_to_stop_streaming_keeps_the_scans_and_names_its_telegram(scripted):
    def scan(r):
        return encode_telegram(encode_scan_values(np.full(2, r)), 0x80)

    power_on = encode_telegram(b"\x90" + b"LMS200;30106" + b"\x10", 0x80)
    transport, lms = make(scripted, [(req("20 24"), ACK + rep("A0 00")),
                                     (req("20 25"), ACK + scan(1.0) + power_on + scan(2.0))])
    lms.n_values, lms.unit = 2, 0.001
    lms.start_streaming()
    with pytest.raises(LmsDeviceReset, match="telegram 0x90"):
        lms.stop_streaming()
    assert [scan.ranges[0] for scan, _ in lms.drain_streamed()] == [1.0, 2.0]
    assert lms.stats["resets"] == 1
    lms.close()


class NeverQuiet:
    """A port whose bytes never stop: an LMS streaming 2-value scans that no request stops."""

    baudrate, timeout, port = 38400, 0.0, "streaming"

    def __init__(self):
        self.writes = 0
        self._frame = scan_frame(7.0)
        self._at = 0

    def write(self, data):
        self.writes += 1
        return len(data)

    def read(self, size=1):
        time.sleep(0.001)
        stream = self._frame * 3
        chunk = stream[self._at : self._at + 20]
        self._at = (self._at + 20) % len(self._frame)
        return chunk


def test_a_request_on_a_line_that_never_falls_silent_ends():
    lms = Lms2xx(NeverQuiet(), timeout=0.2, reply_timeout=0.05, gap_timeout=0.01, attempts=3, settle=0.0)
    # each of 3 sends waits 50 ms and two frames more (~0.1 s at 20 bytes a ms); before, the first never ended
    raises_without_hanging(LmsProtocolError, lms.status)
    assert lms.transport.writes == 3 and lms.stats["broken"] == 3


def test_loop_transport_own_echo_is_not_a_reply():
    import serial  # pyserial is a core dependency
    port = serial.serial_for_url("loop://", timeout=0.01)
    lms = Lms2xx(port, timeout=0.05, reply_timeout=0.02, gap_timeout=0.01)
    with pytest.raises((DeviceTimeout, LmsProtocolError)):
        lms.status()


def test_bad_arguments(scripted):
    with pytest.raises(TypeError, match="transport"):
        Lms2xx(42)
    with pytest.raises(ValueError, match="timeouts"):
        Lms2xx(scripted([]), timeout=0)
    with pytest.raises(ValueError, match="baudrate"):
        Lms2xx(scripted([])).set_baudrate(115200)
