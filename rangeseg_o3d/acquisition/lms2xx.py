"""SICK LMS2xx telegram codec: CRC16, framing, a resynchronising stream decoder, 0xB0 scans.

Pure byte manipulation, no I/O (the driver is :mod:`rangeseg_o3d.acquisition.lms_driver`).
Frame: ``STX 0x02 | address | length (u16 LE) | command, data[, status] | CRC16 (LE)``;
the facts are those of ``shared/docs/protocols.md``.

Examples
--------
>>> encode_telegram(bytes([0x30, 0x01])).hex(" ")
'02 00 02 00 30 01 31 18'
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import LmsDeviceReset, LmsProtocolError

__all__ = [
    "STX",
    "ACK",
    "NAK",
    "MAX_FRAME",
    "crc16",
    "encode_telegram",
    "decode_telegram",
    "Telegram",
    "Ack",
    "Nak",
    "BadFrame",
    "TelegramDecoder",
    "Scan",
    "parse_scan",
    "encode_scan_values",
    "scan_count",
    "beam_angles",
    "SCAN_PERIOD",
    "stream_latency",
    "VARIANTS",
    "MODE_INSTALLATION",
    "MODE_STREAM",
    "MODE_ON_REQUEST",
    "BAUD_MODES",
    "PASSWORD",
]

STX, ACK, NAK = 0x02, 0x06, 0x15
MAX_FRAME = 812
_HEADER = 4  # STX, address, length (2)
MAX_PAYLOAD = MAX_FRAME - _HEADER - 2

MODE_INSTALLATION, MODE_STREAM, MODE_ON_REQUEST = 0x00, 0x24, 0x25
PASSWORD = b"SICK_LMS"
#: host baud rate -> mode byte of the 0x20 telegram that switches to it
BAUD_MODES = {38400: 0x40, 19200: 0x41, 9600: 0x42, 500000: 0x48}
#: (field of view deg, resolution in 1/100 deg) -> number of values per scan
VARIANTS = {(180, 100): 181, (180, 50): 361, (100, 100): 101, (100, 50): 201, (100, 25): 401}

#: replies that announce a power-on or reset of the device
_RESET_CODES = (0x90, 0x91)
#: values >= this are no point (no return, dazzle, overflow, low SNR, read error, too far)
FIRST_SPECIAL = 0x1FF7
_UNIT_METRES = {0: 0.01, 1: 0.001}  # count-word bits 14-15: 00 cm, 01 mm


def crc16(data: bytes) -> int:
    """SICK LMS2xx CRC16 (polynomial 0x8005 over a two-byte window; not a standard CRC).

    Parameters
    ----------
    data : bytes
        Everything from STX to the last byte before the CRC.

    Returns
    -------
    int
        16-bit CRC; it goes on the wire low byte first.

    Examples
    --------
    >>> hex(crc16(bytes.fromhex("02 00 01 00 31")))
    '0x1215'
    """
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise TypeError(f"data must be bytes; got {type(data).__name__}")
    crc = 0
    prev = 0
    for b in bytes(data):
        window = (prev << 8) | b
        prev = b
        if crc & 0x8000:
            crc = ((crc & 0x7FFF) << 1) ^ 0x8005
        else:
            crc = (crc << 1) & 0xFFFF
        crc ^= window
    return crc


def encode_telegram(payload: bytes, address: int = 0) -> bytes:
    """Frame ``payload`` (command byte + data [+ status for replies]) as a complete telegram.

    Parameters
    ----------
    payload : bytes
        Command byte followed by its data, 1 .. 806 bytes.
    address : int
        0x00 for host -> LMS; 0x80 | unit address for LMS -> host.

    Returns
    -------
    bytes
        ``02 address len_lo len_hi payload crc_lo crc_hi``.
    """
    if not isinstance(payload, (bytes, bytearray)):
        raise TypeError(f"payload must be bytes; got {type(payload).__name__}")
    if not 1 <= len(payload) <= MAX_PAYLOAD:
        raise ValueError(f"payload must hold 1 to {MAX_PAYLOAD} bytes; got {len(payload)}")
    if not 0 <= address <= 0xFF:
        raise ValueError(f"address must be a byte (0..255); got {address}")
    frame = bytes([STX, address, len(payload) & 0xFF, len(payload) >> 8]) + bytes(payload)
    crc = crc16(frame)
    return frame + bytes([crc & 0xFF, crc >> 8])


@dataclass(frozen=True)
class Telegram:
    """A decoded telegram. For replies ``status`` is the last payload byte, else None."""

    address: int
    command: int
    data: bytes
    status: int | None = None

    @property
    def is_reply(self) -> bool:
        return bool(self.address & 0x80)

    @property
    def severity(self) -> int:
        """Status bits 0-2: 0 ok, 1 info, 2 warning, 3 error, 4 fatal (0 for requests)."""
        return (self.status or 0) & 0x07


@dataclass(frozen=True)
class Ack:
    """A lone ACK byte (0x06)."""


@dataclass(frozen=True)
class Nak:
    """A lone NAK byte (0x15): the device rejected the last telegram's framing or CRC."""


@dataclass(frozen=True)
class BadFrame:
    """A plausible frame header whose CRC did not match (``reason`` says why)."""

    reason: str


def _split(frame: bytes) -> Telegram:
    address = frame[1]
    payload = frame[_HEADER:-2]
    if address & 0x80:
        if len(payload) < 2:
            raise LmsProtocolError(f"reply payload must hold command and status; got {len(payload)} bytes")
        return Telegram(address, payload[0], bytes(payload[1:-1]), payload[-1])
    return Telegram(address, payload[0], bytes(payload[1:]))


def decode_telegram(frame: bytes) -> Telegram:
    """Decode exactly one complete telegram (no leading or trailing bytes).

    Raises
    ------
    LmsProtocolError
        On a wrong STX, length, size or CRC.
    """
    if not isinstance(frame, (bytes, bytearray, memoryview)):
        raise TypeError(f"frame must be bytes; got {type(frame).__name__}")
    frame = bytes(frame)
    if len(frame) < _HEADER + 3:
        raise LmsProtocolError(f"a telegram has at least 7 bytes; got {len(frame)}")
    if frame[0] != STX:
        raise LmsProtocolError(f"a telegram starts with STX 0x02; got 0x{frame[0]:02X}")
    length = frame[2] | (frame[3] << 8)
    if len(frame) != _HEADER + length + 2:
        raise LmsProtocolError(
            f"length field says {length} payload bytes, so {length + 6} bytes in all; got {len(frame)}"
        )
    crc = crc16(frame[:-2])
    got = frame[-2] | (frame[-1] << 8)
    if crc != got:
        raise LmsProtocolError(f"CRC mismatch: computed 0x{crc:04X}, telegram says 0x{got:04X}")
    return _split(frame)


class TelegramDecoder:
    """Incremental decoder of a byte stream; resynchronises on garbage.

    Feed bytes with :meth:`feed`, take events with :meth:`events`: :class:`Telegram`,
    :class:`Ack`, :class:`Nak` or :class:`BadFrame`. Bytes that belong to no valid
    frame are skipped; after a CRC failure the search restarts one byte after the
    false STX, and lone ACK/NAK inside the rejected frame are not reported (they were
    data, not handshakes).

    Parameters
    ----------
    replies : bool
        True to decode LMS -> host traffic (address has bit 7 set, ACK/NAK reported);
        False for host -> LMS requests (address < 0x80).
    """

    def __init__(self, *, replies: bool = True):
        self.replies = replies
        self._buf = bytearray()
        self._quiet = 0  # bytes before this index are inside a rejected frame

    def clear(self) -> None:
        """Drop everything buffered (after a timeout, before a resend)."""
        self._buf.clear()
        self._quiet = 0

    @property
    def pending(self) -> bool:
        """True when a frame has started but is not complete yet."""
        return STX in self._buf

    def feed(self, data: bytes) -> None:
        self._buf += data

    def _header_ok(self, i: int) -> bool:
        buf = self._buf
        address = buf[i + 1]
        if bool(address & 0x80) != self.replies:
            return False
        length = buf[i + 2] | (buf[i + 3] << 8)
        return (2 if self.replies else 1) <= length <= MAX_PAYLOAD

    def _complete_frame_after(self, i: int) -> int | None:
        """Start of a later complete, CRC-valid frame, or None."""
        buf = self._buf
        j = buf.find(STX, i + 1)
        while 0 <= j <= len(buf) - _HEADER:
            if self._header_ok(j):
                end = j + _HEADER + (buf[j + 2] | (buf[j + 3] << 8)) + 2
                if end <= len(buf) and crc16(buf[j : end - 2]) == (buf[end - 2] | (buf[end - 1] << 8)):
                    return j
            j = buf.find(STX, j + 1)
        return None

    def events(self) -> list:
        """Decode everything decodable so far; incomplete frames stay buffered."""
        out = []
        buf = self._buf
        i = 0
        while i < len(buf):
            b = buf[i]
            if b != STX:
                if self.replies and i >= self._quiet and b in (ACK, NAK):
                    out.append(Ack() if b == ACK else Nak())
                i += 1
                continue
            if len(buf) - i < _HEADER:
                break
            if not self._header_ok(i):
                i += 1
                continue
            end = i + _HEADER + (buf[i + 2] | (buf[i + 3] << 8)) + 2
            if end > len(buf):
                later = self._complete_frame_after(i)
                if later is None:
                    break
                i = later  # the STX at i was garbage that hid a real frame
                continue
            frame = bytes(buf[i:end])
            crc = crc16(frame[:-2])
            if crc != (frame[-2] | (frame[-1] << 8)):
                out.append(BadFrame(f"CRC mismatch in a {len(frame)}-byte frame"))
                self._quiet = max(self._quiet, end)
                i += 1
                continue
            out.append(_split(frame))
            i = end
        del buf[:i]
        self._quiet = max(0, self._quiet - i)
        return out


@dataclass(frozen=True)
class Scan:
    """One parsed 0xB0 scan.

    Attributes
    ----------
    ranges : (n,) float array, metres, NaN where the value was special (>= 0x1FF7).
    raw : (n,) uint16 array of the distance words with the flag bits removed.
    flags : (n,) uint8 array of bits 13-15 (field A, field B, dazzle).
    unit : float, metres per count (0.001 mm mode, 0.01 cm mode).
    status : int, the status byte.
    partial : bool, the partial-scan flag of the count word.
    """

    ranges: np.ndarray
    raw: np.ndarray
    flags: np.ndarray
    unit: float
    status: int
    partial: bool = False


def scan_count(fov: int, resolution: int) -> int:
    """Values per scan for a variant (degrees, 1/100 degree); ValueError if not a variant."""
    try:
        return VARIANTS[(int(fov), int(resolution))]
    except KeyError:
        raise ValueError(
            f"(fov, resolution) must be one of {sorted(VARIANTS)}; got ({fov}, {resolution})"
        ) from None


#: one revolution of the LMS2xx mirror (75 Hz): one scan per period at 1 deg
SCAN_PERIOD = 1.0 / 75.0


def stream_latency(n_values: int, baudrate: int) -> float:
    """Seconds from the middle of a streamed scan's measurement to its last byte's arrival.

    The scan is measured during one mirror revolution (its middle half a period before the
    revolution ends) and then sent: STX, address, length, command, count word, 2 bytes per
    value, status and CRC, 10 bits a byte (8N1) at ``baudrate``.

    Examples
    --------
    >>> round(stream_latency(181, 38400) * 1000, 1)
    103.5
    """
    if n_values < 1 or baudrate <= 0:
        raise ValueError(f"n_values must be >= 1 and baudrate > 0; got {n_values}, {baudrate}")
    return SCAN_PERIOD / 2 + (2 * n_values + 10) * 10 / baudrate


def beam_angles(fov: int, resolution: int) -> np.ndarray:
    """Beam angles (rad) of a variant: 0..180 deg, or 40..140 deg for the 100 deg field."""
    n = scan_count(fov, resolution)
    first = 0.0 if int(fov) == 180 else 40.0
    return np.deg2rad(first + np.arange(n) * int(resolution) / 100.0)


def parse_scan(
    telegram: Telegram,
    *,
    expected_count: int | None = None,
    expected_unit: float | None = None,
    index_bytes: bool = False,
) -> Scan:
    """Parse a 0xB0 reply, checking the count word against the telegram length.

    Parameters
    ----------
    telegram : Telegram
        A decoded reply with command 0xB0.
    expected_count : int, optional
        Reject a scan with a different number of values.
    expected_unit : float, optional
        Reject a scan in other units (0.001 for mm, 0.01 for cm).
    index_bytes : bool
        True when the configuration enables the 2 scan-index bytes after the values.

    Raises
    ------
    LmsProtocolError
        On any inconsistency (wrong command, count, length, unit, error status).
    """
    if not isinstance(telegram, Telegram):
        raise TypeError(f"telegram must be a Telegram; got {type(telegram).__name__}")
    if telegram.command in _RESET_CODES:
        raise LmsDeviceReset(f"power-on/reset telegram 0x{telegram.command:02X} instead of a scan")
    if telegram.command != 0xB0:
        raise LmsProtocolError(f"a scan reply has command 0xB0; got 0x{telegram.command:02X}")
    data = telegram.data
    if len(data) < 2:
        raise LmsProtocolError(f"a scan reply needs a count word; got {len(data)} data bytes")
    word = data[0] | (data[1] << 8)
    n = word & 0x3FF
    unit_bits = (word >> 14) & 0x3
    if unit_bits not in _UNIT_METRES:
        raise LmsProtocolError(f"count word unit bits must be 00 (cm) or 01 (mm); got {unit_bits:02b}")
    expected_len = 2 + 2 * n + (2 if index_bytes else 0)
    if len(data) != expected_len:
        raise LmsProtocolError(
            f"count word announces {n} values ({expected_len} data bytes); got {len(data)}"
        )
    if expected_count is not None and n != expected_count:
        raise LmsProtocolError(f"expected {expected_count} values per scan; got {n}")
    unit = _UNIT_METRES[unit_bits]
    if expected_unit is not None and unit != expected_unit:
        raise LmsProtocolError(f"expected unit {expected_unit} m; scan is in {unit} m")
    if telegram.severity >= 3:
        raise LmsProtocolError(f"device reports an error in status byte 0x{telegram.status:02X}")
    words = np.frombuffer(data, dtype="<u2", count=n, offset=2)
    raw = (words & 0x1FFF).astype(np.uint16)
    flags = (words >> 13).astype(np.uint8)
    ranges = np.where(raw >= FIRST_SPECIAL, np.nan, raw * unit)
    return Scan(ranges, raw, flags, unit, int(telegram.status), partial=bool(word & 0x2000))


def encode_scan_values(ranges_m, *, unit: float = 0.001, status: int = 0x10) -> bytes:
    """Payload of a 0xB0 reply (command, count word, values, status) for ``ranges_m``.

    Non-finite, non-positive or too-far ranges become 0x1FFF (no return) / 0x1FF7 (too far).
    Used by the simulator and by tests.
    """
    r = np.asarray(ranges_m, dtype=float)
    if r.ndim != 1 or not 1 <= r.size <= 0x3FF:
        raise ValueError(f"ranges_m must be 1-D with 1..1023 values; got shape {r.shape}")
    unit_bits = {0.01: 0, 0.001: 1}.get(unit)
    if unit_bits is None:
        raise ValueError(f"unit must be 0.01 (cm) or 0.001 (mm); got {unit}")
    counts = np.full(r.size, 0x1FFF, dtype=np.int64)
    finite = np.isfinite(r) & (r > 0)
    counts[finite] = np.rint(r[finite] / unit).astype(np.int64)
    counts[finite & (counts >= FIRST_SPECIAL)] = 0x1FF7
    word = r.size | (unit_bits << 14)
    return (
        bytes([0xB0, word & 0xFF, word >> 8])
        + counts.astype("<u2").tobytes()
        + bytes([status])
    )
