"""The shipped protocol test helper (expected_protocol, ScriptedTransport) and the debug log of every exchange."""

import doctest
import logging
import threading
import time

import pytest

from rangeseg_o3d.acquisition import testing
from rangeseg_o3d.acquisition.errors import LmsProtocolError
from rangeseg_o3d.acquisition.lms2xx import encode_telegram
from rangeseg_o3d.acquisition.lms_driver import Lms2xx
from rangeseg_o3d.acquisition.logged_transport import LoggedTransport
from rangeseg_o3d.acquisition.powercube import FROM_MODULE, encode_frame
from rangeseg_o3d.acquisition.powercube_driver import PowerCube
from rangeseg_o3d.acquisition.testing import ProtocolMismatch, ScriptedTransport, expected_protocol
from rangeseg_o3d.acquisition.transport import open_transport

from acquisition_helpers import raises_without_hanging

ACK = b"\x06"
MODE_25 = bytes.fromhex("02 00 02 00 20 25 35 08")
MODE_25_OK = ACK + bytes.fromhex("02 81 03 00 A0 00 10 36 1A")
FAST = dict(timeout=0.3, reply_timeout=0.1, gap_timeout=0.01, settle=0.0)
LOGGER = "rangeseg_o3d.acquisition.logged_transport"


def test_the_module_doctest_runs():
    assert doctest.testmod(testing).failed == 0


def test_expected_protocol_passes_when_every_exchange_happens():
    with expected_protocol(Lms2xx, [(MODE_25, MODE_25_OK)], **FAST) as lms:
        lms.set_mode(0x25)
    assert lms.transport.writes == [MODE_25]


def test_a_different_write_names_both():
    with pytest.raises(ProtocolMismatch, match="write 1 expected 02 00 02 00 20 25 35 08, got 02 00 02 00 20 48"):
        with expected_protocol(Lms2xx, [(MODE_25, MODE_25_OK)], **FAST) as lms:
            lms.set_mode(0x48)


def test_an_exchange_left_unused_fails_on_leaving_the_block():
    with pytest.raises(ProtocolMismatch, match=r"1 scripted exchange\(s\) never happened \(next expected write: 02 00"):
        with expected_protocol(Lms2xx, [(MODE_25, MODE_25_OK), (MODE_25, MODE_25_OK)], **FAST) as lms:
            lms.set_mode(0x25)


def test_a_write_after_the_script_ends_fails():
    with pytest.raises(ProtocolMismatch, match="unexpected write 02 00 02 00 20 25 35 08: the script is exhausted"):
        with expected_protocol(Lms2xx, [], **FAST) as lms:
            lms.set_mode(0x25)


def test_the_drivers_own_error_is_what_the_test_sees():
    refused = ACK + encode_telegram(bytes.fromhex("A0 01 10"), 0x80)
    with pytest.raises(LmsProtocolError, match="refused mode 0x25"):
        with expected_protocol(Lms2xx, [(MODE_25, refused), (MODE_25, refused)], **FAST) as lms:
            lms.set_mode(0x25)  # raises: the unused second exchange is not reported over it


def test_every_exchange_is_debug_logged_in_both_directions(caplog):
    caplog.set_level(logging.DEBUG, logger=LOGGER)
    with expected_protocol(Lms2xx, [(MODE_25, MODE_25_OK)], port="lms-fake", **FAST) as lms:
        lms.set_mode(0x25)
    lines = [r.getMessage() for r in caplog.records if r.name == LOGGER]
    assert lines[0] == "lms-fake > 02 00 02 00 20 25 35 08"
    received = bytes.fromhex("".join(line.split(" < ")[1].replace(" ", "") for line in lines[1:]))
    assert received == MODE_25_OK and all(" < " in line for line in lines[1:])


def test_powercube_exchanges_are_logged_too(caplog):
    caplog.set_level(logging.DEBUG, logger=LOGGER)
    reset = bytes.fromhex("02 05 61 00 66 03")
    with expected_protocol(PowerCube, [(reset, encode_frame(11, b"\x00", direction=FROM_MODULE))],
                           timeout=0.2, reply_timeout=0.02, poll_interval=0.0) as cube:
        cube.reset()
    assert [r.getMessage() for r in caplog.records if r.name == LOGGER][0] == "scripted > 02 05 61 00 66 03"


def test_quiet_by_default(caplog):
    caplog.set_level(logging.INFO)
    with expected_protocol(Lms2xx, [(MODE_25, MODE_25_OK)], **FAST) as lms:
        lms.set_mode(0x25)
    assert [r for r in caplog.records if r.name == LOGGER] == []


def test_the_logged_transport_is_transparent():
    fake = ScriptedTransport([(b"\x01", b"\x02\x03")], port="p0", baudrate=9600)
    wrapped = open_transport(fake, baudrate=9600)
    assert isinstance(wrapped, LoggedTransport) and wrapped.inner is fake
    assert open_transport(wrapped, baudrate=9600).inner is fake  # never wrapped twice
    wrapped.baudrate = 38400  # attribute writes reach the port
    assert fake.baudrate == 38400 and wrapped.port == "p0"
    assert wrapped.write(b"\x01") == 1 and wrapped.in_waiting == 2
    assert wrapped.read(5) == b"\x02\x03" and wrapped.read(1) == b""
    fake.verify()
    with pytest.raises(AttributeError):
        wrapped.no_such_attribute


def test_a_named_port_is_logged_under_its_name(caplog):
    pytest.importorskip("serial")
    caplog.set_level(logging.DEBUG, logger=LOGGER)
    port = open_transport("loop://", baudrate=9600, timeout=0.01)
    port.write(b"\xab\xcd")
    assert port.read(2) == b"\xab\xcd"
    port.close()
    assert [r.getMessage() for r in caplog.records if r.name == LOGGER] == ["loop:// > ab cd", "loop:// < ab cd"]


def test_chunk_reader_dates_chunks_by_arrival_and_reports_a_dead_port():
    from rangeseg_o3d.acquisition.transport import ChunkReader

    class Vanishing(ScriptedTransport):
        def read(self, size=1):
            if self.gone:
                raise OSError(5, "Input/output error")
            return super().read(size)

    port = Vanishing([])
    port.gone = False
    with pytest.raises(ValueError, match="wait must be positive; got 0"):
        ChunkReader(port, 0)
    reader = ChunkReader(port, 0.005)
    # the clock is read before the bytes are put: the reader thread may take them at once
    arrived = time.monotonic()
    port._rx += b"ab"
    time.sleep(0.1)
    (stamp, data), = reader.take()
    assert data == b"ab" and 0 <= stamp - arrived < 0.05
    port.gone = True
    with pytest.raises(OSError, match="Input/output"):
        reader.take(wait=0.5)
    reader.stop()
    assert not reader.running


def test_stream_latency_is_half_a_revolution_and_the_transfer():
    from rangeseg_o3d.acquisition.lms2xx import SCAN_PERIOD, stream_latency

    assert stream_latency(181, 500000) == pytest.approx(SCAN_PERIOD / 2 + 372 * 10 / 500000)
    with pytest.raises(ValueError, match="baudrate > 0; got 181, 0"):
        stream_latency(181, 0)


def test_a_take_waiting_for_chunks_ends_when_the_reader_thread_ends():
    from rangeseg_o3d.acquisition.transport import ChunkReader

    class Vanishing(ScriptedTransport):
        def read(self, size=1):
            time.sleep(0.05)
            raise OSError(5, "Input/output error")

    reader = ChunkReader(Vanishing([]), 0.005)
    # the thread dies 50 ms in; before, take() waited out its 30 s
    raises_without_hanging(OSError, lambda: reader.take(wait=30.0), match="Input/output")
    with pytest.raises(OSError):
        reader.take(wait=30.0)  # the thread has ended: no wait at all, its error again
    with pytest.raises(ValueError, match="finite"):
        reader.take(wait=float("inf"))
    reader.stop()


def test_stopping_a_reader_stuck_in_a_read_is_an_error_not_a_hang():
    from rangeseg_o3d.acquisition.errors import AcquisitionError
    from rangeseg_o3d.acquisition.transport import ChunkReader

    release = threading.Event()

    class Stuck(ScriptedTransport):
        def read(self, size=1):
            release.wait()  # ignores its timeout, as a wedged driver may
            return b""

    reader = ChunkReader(Stuck([], port="stuck"), 0.005)
    # before, stop() joined the thread for ever
    raises_without_hanging(AcquisitionError, lambda: reader.stop(timeout=0.2),
                           match="thread reading stuck did not stop within 0.2 s")
    release.set()
    reader.stop()
    assert not reader.running


def test_stopping_a_reader_whose_wait_is_longer_than_the_stop_timeout_is_no_error():
    # a port that honours its read timeout is not stuck: stop() waits out the read that began
    # before it (before: stop(timeout=0.05) on a 0.4 s wait raised 'did not stop within 0.05 s')
    from rangeseg_o3d.acquisition.transport import ChunkReader

    class Honest(ScriptedTransport):
        def read(self, size=1):
            time.sleep(self.timeout)  # nothing arrives: the read takes its whole timeout
            return b""

    reader = ChunkReader(Honest([], port="honest"), 0.4)
    time.sleep(0.05)  # the thread is in its first read
    reader.stop(timeout=0.05)
    assert not reader.running
