"""Driver for a SICK LMS2xx on a serial line: handshakes, retries, baud detection, scans."""

from __future__ import annotations

import logging
import time

import numpy as np

from .errors import SILENT_REQUESTS, DeviceTimeout, LmsDeviceReset, LmsProtocolError
from .lms2xx import (
    BAUD_MODES,
    MAX_FRAME,
    MODE_INSTALLATION,
    MODE_ON_REQUEST,
    MODE_STREAM,
    PASSWORD,
    ACK,
    Ack,
    BadFrame,
    Nak,
    Scan,
    Telegram,
    TelegramDecoder,
    encode_telegram,
    parse_scan,
    scan_count,
)
from .consensus import consensus
from .transport import ChunkReader, open_transport, port_name, read_some, sleep

__all__ = ["Lms2xx", "PROBE_ORDER"]

log = logging.getLogger(__name__)

PROBE_ORDER = (9600, 19200, 38400, 500000)
_RESET_CODES = (0x90, 0x91)
_UNITS_BYTE = 6  # index of the units byte in the configuration block
_UNIT_M = {"mm": 0.001, "cm": 0.01}
_PROBE_SWEEPS = 3
# Bytes received past reply_timeout without the reply that end a wait on a line whose bytes
# never stop: a reply still arriving at reply_timeout is at most one frame.
_BUSY_LINE_BYTES = 2 * MAX_FRAME


class Lms2xx:
    """A SICK LMS200/LMS2xx laser scanner.

    Parameters
    ----------
    port : str or transport
        Port name (opened with pyserial at ``initial_baudrate``) or a transport object.
    initial_baudrate : int
        Rate to try first (the power-up rate is 9600).
    timeout : float
        Seconds of complete silence after which :class:`DeviceTimeout` is raised.
    reply_timeout : float
        Seconds to wait for one reply before resending (the LMS answers within 1 s).
    gap_timeout : float
        A started but incomplete telegram followed by this much silence is abandoned
        (a byte was lost) and the request is sent again.
    nak_delay : float
        Pause before resending after a NAK (a real device needs at least 30 ms; the
        simulator's time runs faster, so its host waits less).
    attempts : int
        Sends per command before giving up with :class:`LmsProtocolError`.
    settle : float
        Pause after the host changes its baud rate.
    mode_timeout : float
        Reply timeout of a baud-rate change (up to 3 s).
    config_timeout : float
        Reply timeout of a configuration write (EEPROM: 7-15 s).
    probe_timeout : float
        Reply timeout of one baud-rate probe.
    ack_timeout : float, optional
        A scan request answered by nothing at all (not even the ACK, which the LMS sends
        at once) for this long was lost on the line and is resent without waiting the
        whole ``reply_timeout``. None (default): wait ``reply_timeout``.
    """

    def __init__(
        self,
        port,
        *,
        initial_baudrate: int = 9600,
        timeout: float = 3.0,
        reply_timeout: float = 1.0,
        gap_timeout: float = 0.05,
        nak_delay: float = 0.03,
        attempts: int = 10,
        settle: float = 0.25,
        config_timeout: float = 15.0,
        mode_timeout: float = 3.0,
        probe_timeout: float = 0.2,
        ack_timeout: float | None = None,
    ):
        if timeout <= 0 or reply_timeout <= 0 or gap_timeout <= 0:
            raise ValueError(
                f"timeouts must be positive; got timeout={timeout}, reply_timeout={reply_timeout}, "
                f"gap_timeout={gap_timeout}"
            )
        if attempts < 1:
            raise ValueError(f"attempts must be >= 1; got {attempts}")
        self.transport = open_transport(port, baudrate=initial_baudrate, timeout=gap_timeout)
        self.port = port_name(self.transport) if not isinstance(port, str) else port
        self.timeout = timeout
        self.reply_timeout = reply_timeout
        self.gap_timeout = gap_timeout
        self.nak_delay = max(0.0, float(nak_delay))
        self.attempts = attempts
        self.settle = settle
        self.config_timeout = config_timeout
        self.mode_timeout = mode_timeout
        self.probe_timeout = probe_timeout
        self.ack_timeout = ack_timeout
        self.n_values: int | None = None
        self.unit: float | None = None
        # damaged_scans: streamed scans left out, their telegram damaged on the line (CRC) or inconsistent
        self.stats = {"sent": 0, "nak": 0, "bad_frames": 0, "broken": 0, "silent": 0, "resets": 0,
                      "damaged_scans": 0}
        self._decoder = TelegramDecoder(replies=True)
        self._backlog: list = []  # events decoded after a reply (scans streamed with it), kept for start_streaming
        self._reply_at = 0.0  # host time the chunk holding the last reply arrived
        self._received = bytearray()
        self._streaming = False
        self._reader: ChunkReader | None = None  # reads the port while the LMS streams
        self._streamed: list[tuple[Scan, float]] = []  # (scan, arrival) not taken yet
        # True while a request sent earlier may still be answered: a send ended without its
        # reply (unanswered in time, damaged, NAK) or was left behind by a resend. See _settle.
        self._unsettled = False

    # -- low level --------------------------------------------------------------
    def close(self) -> None:
        """End a threaded read of the stream and close the port (closed even if the thread is stuck)."""
        reader, self._reader = self._reader, None
        try:
            if reader is not None:
                reader.stop()
        finally:
            close = getattr(self.transport, "close", None)
            if callable(close):
                close()

    def _flush(self) -> None:
        reset = getattr(self.transport, "reset_input_buffer", None)
        if callable(reset):
            reset()
        self._decoder.clear()
        self._backlog = []

    def _await(self, reply_code: int, reply_timeout: float,
               ack_timeout: float | None = None) -> tuple[str, Telegram | None, bool]:
        """Wait for one reply: ('reply', t, heard) | ('nak'|'broken'|'silent', None, heard).

        A frame that arrives whole but fails its CRC ends the wait at once ('broken'): the
        request is resent without waiting for a gap that would tell nothing more. Not while
        the LMS streams: then it is most likely a scan damaged on the line, which says nothing
        about the request (no NAK, no reply yet), and the frames after it in the same read may
        be good scans or the reply itself. The wait goes on; a damaged reply is resent after
        the gap that follows it (a stream being stopped) or after ``reply_timeout``.

        Bytes that never stop without bringing the reply end the wait ('broken') once
        ``_BUSY_LINE_BYTES`` (two frames) have come past ``reply_timeout``: a reply still
        arriving then is at most one frame, and a host descheduled past the deadline still
        reads what arrived meanwhile (counted by bytes, not time, so that is no reason to end).
        """
        start = time.monotonic()
        last_rx = None
        only_ack = True
        late = 0  # bytes received past reply_timeout
        self._received = bytearray()  # what this reply brought, for rebuilding a damaged scan
        while True:
            now = time.monotonic()
            wait = min(self.gap_timeout, reply_timeout - (now - start))
            data = read_some(self.transport, max(wait, 0.001))
            if not data:
                # Timeouts are judged only after a read came back empty, so a host that was
                # descheduled for a while reads what arrived meanwhile before deciding.
                now = time.monotonic()
                if now - start > reply_timeout:
                    return ("silent" if last_rx is None else "broken"), None, last_rx is not None
                if last_rx is None and ack_timeout is not None and now - start > ack_timeout:
                    return "silent", None, False
                if last_rx is not None and not only_ack and now - last_rx > self.gap_timeout:
                    return "broken", None, True
                continue
            last_rx = time.monotonic()
            if last_rx - start > reply_timeout:
                late += len(data)
            self._received += data
            if data.strip(bytes([ACK])):
                only_ack = False  # a reply has started: from now on a gap means a lost byte
            self._decoder.feed(data)
            events = self._decoder.events()
            for n, event in enumerate(events):
                if isinstance(event, Ack):
                    continue
                if isinstance(event, Nak):
                    return "nak", None, True
                if isinstance(event, BadFrame):
                    if self._streaming:
                        self.stats["damaged_scans"] += 1
                        continue
                    self.stats["bad_frames"] += 1
                    return "broken", None, True
                if event.command == reply_code:
                    self._backlog = events[n + 1 :]
                    self._reply_at = last_rx
                    return "reply", event, True
                if event.command in _RESET_CODES:
                    if self._streaming:  # keeps the scans that came after it; the reset is counted and raised below
                        self._keep_scans(events[n + 1 :], last_rx)
                    self.stats["resets"] += 1
                    raise LmsDeviceReset(
                        f"LMS on {self.port} sent power-on/reset telegram 0x{event.command:02X}"
                    )
                if event.command == 0x92:
                    raise LmsProtocolError(
                        f"LMS on {self.port} rejected the request (0x92, data {event.data.hex(' ')})"
                    )
                if self._streaming and event.command == 0xB0:
                    self._keep_scans([event], last_rx)  # streamed before the device heard us
                # anything else is a stale reply or a streamed scan: not ours
            if late > _BUSY_LINE_BYTES:
                # A line that never falls silent (a stream the request did not stop, a babbling
                # port) gives no empty read to judge the timeouts by: the wait still ends.
                return "broken", None, True

    def request(
        self,
        payload: bytes,
        reply_code: int | None = None,
        *,
        attempts: int | None = None,
        reply_timeout: float | None = None,
        timeout: float | None = None,
        ack_timeout: float | None = None,
        rescue=None,
        keep_input: bool = False,
    ) -> Telegram:
        """Send ``payload`` and return the reply telegram, resending after NAK or corruption.

        Raises
        ------
        DeviceTimeout
            Nothing at all came back for ``timeout`` seconds.
        LmsProtocolError
            Only invalid answers came back ``attempts`` times.
        LmsDeviceReset
            The device announced a power-on / reset.

        ``keep_input`` keeps what was received before the first send (a scan the LMS is
        still streaming). Resends start afresh (stale bytes dropped), except while the LMS
        streams: then every byte received is data (scans, or the reply to an earlier send),
        so nothing is dropped. A request ends a threaded read of the stream.
        """
        if self._reader is not None:
            self._end_reader()
        reply_code = (payload[0] + 0x80) if reply_code is None else reply_code
        attempts = self.attempts if attempts is None else attempts
        reply_timeout = self.reply_timeout if reply_timeout is None else reply_timeout
        timeout = self.timeout if timeout is None else timeout
        frame = encode_telegram(bytes(payload))
        if rescue is None and attempts > 2:
            rescue = self._rescue(reply_code)
        silent_since = time.monotonic()
        silent_in_a_row = 0
        unsettled_before = self._unsettled
        for attempt in range(attempts):
            if not (keep_input if attempt == 0 else self._streaming):
                self._flush()
            self.transport.write(frame)
            self.stats["sent"] += 1
            self._unsettled = True  # until this send's reply is in: a failure or a resend leaves it owed
            remaining = timeout - (time.monotonic() - silent_since)
            outcome, telegram, heard = self._await(reply_code, min(reply_timeout, max(remaining, 0.001)),
                                                   ack_timeout)
            if heard:
                silent_since = time.monotonic()
            if outcome == "reply":
                # The one send of this call answered: nothing more is owed than before. After a
                # resend, the reply taken may answer an earlier send and the last one's is owed.
                self._unsettled = unsettled_before if attempt == 0 else True
                return telegram
            self.stats[outcome] += 1
            if outcome == "broken" and rescue is not None:
                telegram = rescue(bytes(self._received).lstrip(bytes([ACK])))
                if telegram is not None:
                    return telegram
            silent_in_a_row = silent_in_a_row + 1 if outcome == "silent" else 0
            if outcome == "nak":
                sleep(self.nak_delay)
            elif (outcome == "silent" and time.monotonic() - silent_since >= timeout
                  and silent_in_a_row >= min(attempts, SILENT_REQUESTS)):
                raise DeviceTimeout(self.port, timeout, "LMS2xx")
        raise LmsProtocolError(
            f"no valid 0x{reply_code:02X} reply from the LMS on {self.port} after {attempts} attempts"
        )

    # -- commands ---------------------------------------------------------------
    def set_mode(self, mode: int, *, password: bytes = PASSWORD, timeout: float | None = None,
                 keep_input: bool = False) -> None:
        """Operating mode change (0x20); installation mode sends the password."""
        payload = bytes([0x20, mode]) + (password if mode == MODE_INSTALLATION else b"")
        reply = self.request(payload, 0xA0, reply_timeout=max(self.reply_timeout, timeout or 0),
                             keep_input=keep_input)
        if not reply.data or reply.data[0] != 0:
            result = reply.data[0] if reply.data else None
            raise LmsProtocolError(f"LMS refused mode 0x{mode:02X} (result {result})")

    def device_type(self) -> str:
        """Type string (0x3A), e.g. 'LMS200;30106'."""
        return self.request(b"\x3a", 0xBA).data.decode("ascii", "replace").strip("\x00 ")

    def status(self) -> Telegram:
        """Raw status reply (0x31)."""
        return self.request(b"\x31", 0xB1)

    def probe(self, baudrate: int, *, reply_timeout: float | None = None) -> bool:
        """True if the device answers a harmless 20 25 at ``baudrate`` (also stops a stream)."""
        reply_timeout = self.probe_timeout if reply_timeout is None else reply_timeout
        self.transport.baudrate = baudrate
        sleep(min(self.settle, 0.05))
        try:
            self.request(bytes([0x20, MODE_ON_REQUEST]), 0xA0, attempts=2, reply_timeout=reply_timeout,
                         timeout=2 * reply_timeout)
            return True
        except (DeviceTimeout, LmsProtocolError):
            return False

    def detect_baudrate(self, candidates=PROBE_ORDER, *, reply_timeout: float | None = None) -> int:
        """Find the rate the device talks at, current host rate first; leaves the host there.

        Raises
        ------
        DeviceTimeout
            No rate got an answer.
        """
        reply_timeout = self.probe_timeout if reply_timeout is None else reply_timeout
        current = getattr(self.transport, "baudrate", None)
        order = [current] + [b for b in candidates if b != current] if current in candidates else list(candidates)
        # A probe garbled on a noisy line looks like a wrong rate: sweep the rates a few
        # times before calling the device silent.
        for _ in range(_PROBE_SWEEPS):
            for rate in order:
                if self.probe(rate, reply_timeout=reply_timeout):
                    log.info("LMS on %s answers at %d baud", self.port, rate)
                    return rate
        raise DeviceTimeout(self.port, reply_timeout * 2 * len(order) * _PROBE_SWEEPS,
                            f"LMS2xx (probed {order} baud {_PROBE_SWEEPS} times)")

    def set_baudrate(self, baudrate: int) -> None:
        """Switch device and host to ``baudrate`` (reply comes at the old rate), then verify."""
        if baudrate not in BAUD_MODES:
            raise ValueError(f"baudrate must be one of {sorted(BAUD_MODES)}; got {baudrate}")
        if getattr(self.transport, "baudrate", None) == baudrate:
            return
        for _ in range(_PROBE_SWEEPS):
            try:
                self.set_mode(BAUD_MODES[baudrate], timeout=self.mode_timeout)
                self.transport.baudrate = baudrate
                sleep(self.settle)
                self.device_type()
                return
            except (DeviceTimeout, LmsProtocolError) as err:
                if isinstance(err, LmsDeviceReset):
                    raise
                # The device switches right after its confirmation: if that was lost on the
                # line, it now talks at the new rate and the old one hears silence.
                log.info("LMS on %s: baud change to %d unconfirmed (%s); probing", self.port, baudrate, err)
                if self.detect_baudrate() == baudrate:
                    return
        raise LmsProtocolError(f"the LMS on {self.port} did not switch to {baudrate} baud")

    def set_variant(self, fov: int, resolution: int) -> int:
        """Scan variant (0x3B): fov 100/180 degrees, resolution in 1/100 degree; returns values per scan."""
        n = scan_count(fov, resolution)
        payload = bytes([0x3B, fov & 0xFF, fov >> 8, resolution & 0xFF, resolution >> 8])
        reply = self.request(payload, 0xBB)
        if len(reply.data) < 5 or reply.data[0] != 1:
            raise LmsProtocolError(f"LMS rejected variant {fov} deg / {resolution / 100} deg ({reply.data.hex(' ')})")
        echo = (reply.data[1] | reply.data[2] << 8, reply.data[3] | reply.data[4] << 8)
        if echo != (fov, resolution):
            raise LmsProtocolError(f"LMS confirmed variant {echo}, not {(fov, resolution)}")
        self.n_values = n
        return n

    def read_config(self) -> bytes:
        """The configuration block (0x74 -> 0xF4; 34 bytes, 32 on older firmware)."""
        cfg = self.request(b"\x74", 0xF4).data
        if len(cfg) not in (32, 34):
            raise LmsProtocolError(f"configuration block must have 32 or 34 bytes; got {len(cfg)}")
        return cfg

    def set_units(self, units: str = "mm") -> None:
        """Measuring units by read-modify-write of the configuration (skipped when already set)."""
        if units not in _UNIT_M:
            raise ValueError(f"units must be 'mm' or 'cm'; got {units!r}")
        code = 1 if units == "mm" else 0
        installing = False
        for _ in range(_PROBE_SWEEPS):
            cfg = bytearray(self.read_config())
            if cfg[_UNITS_BYTE] == code:
                break
            cfg[_UNITS_BYTE] = code
            self.set_mode(MODE_INSTALLATION)
            installing = True
            try:
                reply = self.request(b"\x77" + bytes(cfg), 0xF7, reply_timeout=self.config_timeout,
                                     timeout=self.config_timeout + self.timeout)
            except LmsProtocolError as err:
                if isinstance(err, LmsDeviceReset):
                    raise
                # On a noisy line the write may have happened and only its long reply been
                # lost: the next round reads the configuration back and stops if it holds.
                log.info("LMS on %s: configuration write unconfirmed (%s); reading it back", self.port, err)
                continue
            if not reply.data or reply.data[0] != 1:
                raise LmsProtocolError("LMS refused the configuration write")
            break
        else:
            raise LmsProtocolError(f"the LMS on {self.port} did not take units {units!r}")
        if installing:
            self.set_mode(MODE_ON_REQUEST)
        self.unit = _UNIT_M[units]

    def initialise(self, *, baudrate: int = 38400, fov: int = 180, resolution: int = 100, units: str = "mm") -> None:
        """Detect the rate, switch to ``baudrate``, send-on-request mode, variant and units."""
        self.detect_baudrate()
        self.set_baudrate(baudrate)
        self.set_mode(MODE_ON_REQUEST)
        self.set_variant(fov, resolution)
        self.set_units(units)

    # -- scans ------------------------------------------------------------------
    def _check(self, telegram: Telegram) -> Scan:
        return parse_scan(telegram, expected_count=self.n_values, expected_unit=self.unit, index_bytes=None)

    def _rescue(self, reply_code: int, length: int | None = None):
        """A ``rescue`` for :meth:`request`: rebuilds a reply from its damaged copies.

        The device repeats the same reply to the same request (a scan at a standstill, a
        configuration block...). ``length`` is the frame's length in bytes; None takes the
        length most copies' headers declare. Tried at 3, 5, 8, 12, 20, 30, ... copies (each
        try costs a few ms per copy) with the newest 40; the rebuilt frame must pass the CRC
        like any other.
        """
        copies: list[bytes] = []
        tries = {3, 5, 8, 12, 20}

        def frame_length() -> int | None:
            declared = [c[2] | c[3] << 8 for c in copies if len(c) > 4 and c[0] == 0x02]
            if not declared:
                return None
            values, counts = np.unique(declared, return_counts=True)
            return int(values[counts.argmax()]) + 6 if counts.max() >= 2 else None

        def rescue(raw: bytes) -> Telegram | None:
            if len(raw) < 6:
                return None
            copies.append(raw)
            del copies[:-40]
            if len(copies) not in tries and (len(copies) < 20 or len(copies) % 10):
                return None
            expected = length if length is not None else frame_length()
            if expected is None or not expected // 2 <= len(raw) <= expected + expected // 2:
                return None
            frame = consensus([c for c in copies if abs(len(c) - expected) <= expected // 4], expected)
            if frame is None:
                return None
            decoder = TelegramDecoder(replies=True)
            decoder.feed(frame)
            for event in decoder.events():
                if isinstance(event, Telegram) and event.command == reply_code:
                    self.stats["rebuilt"] = self.stats.get("rebuilt", 0) + 1
                    log.debug("reply 0x%02X rebuilt from %d damaged copies", reply_code, len(copies))
                    return event
            return None

        return rescue

    def _settle(self) -> None:
        """Wait until every reply still owed to earlier sends has come, by a request the LMS
        answers with another reply code (device type, 3A -> BA).

        The LMS answers the requests it received in order, with no sequence number. A send
        left unanswered in time (a slow device, a lost ACK, a simulator without a core) may
        still be answered later, after the request that follows: a scan measured before or
        during a tilt move would then be taken as the answer to a request made at the next
        stop. Counting the sends owed a reply cannot tell: a request lost on the line is
        never answered. A reply to the fence comes after the replies to everything the LMS
        received before it, so the first scan after it answers a request sent after it.
        """
        self.request(b"\x3a", 0xBA)
        self._unsettled = False
        self.stats["settled"] = self.stats.get("settled", 0) + 1

    def request_scan(self, *, attempts: int | None = None) -> Scan:
        """One complete scan (30 01) in send-on-request mode; resent until CRC, count and unit check.

        The scan returned answers a request sent by this call: when an earlier request may
        still be answered (it was resent or failed), the line is first settled (:meth:`_settle`),
        so a late reply to it is never taken for this one's (it may have been measured at
        another tilt).

        On a line too noisy for a whole copy to arrive, the scan is rebuilt from its damaged
        copies (:mod:`~rangeseg_o3d.acquisition.consensus`; the device repeats a scan at a
        standstill) and must then pass the same checks.
        """
        if self._unsettled:
            self._settle()
        attempts = self.attempts if attempts is None else attempts
        # STX, address, length, command, count, values, status, CRC
        length = None if self.n_values is None else 10 + 2 * self.n_values
        rescue = self._rescue(0xB0, length) if attempts > 1 else None
        for _ in range(attempts):
            telegram = self.request(b"\x30\x01", 0xB0, attempts=attempts, ack_timeout=self.ack_timeout,
                                    rescue=rescue)
            try:
                return self._check(telegram)
            except LmsDeviceReset:
                raise
            except LmsProtocolError as err:
                log.debug("scan rejected: %s", err)
                self.stats["bad_frames"] += 1
        raise LmsProtocolError(f"no consistent scan from the LMS on {self.port} after {attempts} attempts")

    # -- streaming ----------------------------------------------------------------
    def start_streaming(self) -> None:
        """Mode 0x24: the LMS sends scans back to back (every mirror revolution, 75 Hz, when
        the line rate allows) until :meth:`stop_streaming`.

        From the mode reply on, a thread reads the port (:class:`~.transport.ChunkReader`), so
        each scan is dated by when its bytes arrived however busy the host is, and none is
        lost to a host that falls behind. Take them with :meth:`drain_streamed` or
        :meth:`read_streamed`.
        """
        self._streamed = []
        self._streaming = True
        try:
            self.set_mode(MODE_STREAM)
            events, self._backlog = self._backlog, []
            self._keep_scans(events, self._reply_at)  # scans that came with the mode reply
        except BaseException:
            self._streaming = False
            raise
        self._reader = ChunkReader(self.transport, min(self.gap_timeout, 0.01))

    @property
    def streaming(self) -> bool:
        """True from :meth:`start_streaming` until :meth:`stop_streaming`."""
        return self._streaming

    def stop_streaming(self) -> None:
        """Back to send-on-request mode (0x25).

        The scans that arrived until then, and the one in flight while the device took the
        mode change, stay for :meth:`drain_streamed`.
        """
        try:
            self.set_mode(MODE_ON_REQUEST, keep_input=True)
        finally:
            self._streaming = False

    def _end_reader(self) -> None:
        """Stop the threaded read; decode what it and the port still hold."""
        reader, self._reader = self._reader, None
        reader.stop()
        self._decode(reader.take())
        self._decode(self._received_chunks(0.0))  # what came after the thread's last read

    def _received_chunks(self, wait: float) -> list[tuple[float, bytes]]:
        """Chunks received while streaming, each with its arrival time, waiting up to ``wait``."""
        if self._reader is not None:
            return self._reader.take(wait)
        data = read_some(self.transport, wait)
        return [(time.monotonic(), data)] if data else []

    def _decode(self, chunks) -> None:
        """Streamed chunks to scans, each dated by the arrival of the chunk holding its last byte.

        A power-on telegram raises :class:`LmsDeviceReset` once every chunk is decoded: the
        chunks were taken from the reader, so a valid scan among the rest would be lost.
        """
        reset = None
        for arrival, data in chunks:
            self._decoder.feed(data)
            try:
                self._keep_scans(self._decoder.events(), arrival)
            except LmsDeviceReset as err:
                reset = reset or err
        if reset is not None:
            raise reset

    def _keep_scans(self, events, arrival: float) -> None:
        """Keep the valid scans among ``events``, count the damaged ones (``stats["damaged_scans"]``);
        a power-on telegram among them raises :class:`LmsDeviceReset` after the scans that came
        with it are kept."""
        reset = False
        for event in events:
            if isinstance(event, BadFrame):  # a scan whose telegram failed its CRC
                self.stats["damaged_scans"] += 1
                continue
            if not isinstance(event, Telegram):
                continue
            if event.command in _RESET_CODES:
                reset = True
            elif event.command == 0xB0:
                try:
                    self._streamed.append((self._check(event), arrival))
                except LmsProtocolError:
                    self.stats["damaged_scans"] += 1
        if reset:
            self.stats["resets"] += 1
            raise LmsDeviceReset(f"LMS on {self.port} reset while streaming")

    def drain_streamed(self) -> list[tuple[Scan, float]]:
        """Every valid streamed scan received and not taken yet, oldest first, without waiting.

        Each comes with the host time (``time.monotonic``) the chunk holding its last byte
        arrived. Corrupted scans are skipped (counted in ``stats["damaged_scans"]``); a
        power-on telegram raises :class:`LmsDeviceReset`.
        """
        if self._streaming:
            self._decode(self._received_chunks(0.0))
        scans, self._streamed = self._streamed, []
        return scans

    def read_streamed(self, timeout: float) -> tuple[Scan, float] | None:
        """The oldest streamed scan not taken yet and the host time its last byte arrived,
        or None if none arrives within ``timeout`` (see :meth:`drain_streamed`)."""
        deadline = time.monotonic() + timeout
        while not self._streamed:
            remaining = deadline - time.monotonic()
            if remaining <= 0 or not self._streaming:
                return None
            self._decode(self._received_chunks(min(remaining, self.gap_timeout)))
        return self._streamed.pop(0)
