"""Schunk/Amtec PowerCube M5 serial codec: escaped frames with a block check character.

Frame: ``STX 0x02 | H0 | H1 | D0..Dn-1 | BCC | ETX 0x03``; any H0/H1/data/BCC byte
equal to 0x02, 0x03 or 0x10 goes on the wire as ``0x10, byte + 0x80``. Facts from
``shared/docs/protocols.md``. No I/O here (the driver is
:mod:`rangeseg_o3d.acquisition.powercube_driver`).

Examples
--------
>>> encode_frame(11, bytes([0x0A, 0x3C])).hex(" ")
'02 05 62 0a 3c ad 03'
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

import numpy as np

from .errors import PowerCubeProtocolError

__all__ = [
    "STX",
    "ETX",
    "DLE",
    "TO_MODULE",
    "FROM_MODULE",
    "CMD",
    "PARAM",
    "MOTION",
    "STATE",
    "bcc",
    "escape",
    "encode_frame",
    "decode_frame",
    "Frame",
    "FrameDecoder",
    "pack_float",
    "unpack_float",
    "ramp_profile",
    "ramp_time",
]

STX, ETX, DLE = 0x02, 0x03, 0x10
TO_MODULE, FROM_MODULE = 0x04, 0x08
MAX_DATA = 8

CMD = {"reset": 0x00, "home": 0x01, "halt": 0x02, "set": 0x08, "get": 0x0A, "motion": 0x0B, "start": 0x0F}
PARAM = {
    "state": 0x27,
    "position": 0x3C,
    "velocity": 0x41,
    "min_position": 0x45,
    "max_position": 0x46,
    "max_velocity": 0x48,
    "max_acceleration": 0x4A,
    "ramp_velocity": 0x4F,
    "ramp_acceleration": 0x50,
}
MOTION = {"framp": 0x04, "fstep": 0x06, "framp_ext": 0x0E, "fstep_ext": 0x10}
STATE = {
    "error": 0x1,
    "homed": 0x2,
    "halted": 0x4,
    "power_fault": 0x8,
    "tow_error": 0x10,
    "comm_error": 0x20,
    "motion": 0x800,
    "ramp_end": 0x8000,
}
_SPECIAL = (STX, ETX, DLE)


def _ramp_phases(distance: float, velocity: float, acceleration: float) -> tuple[float, float, float]:
    """(time accelerating, time cruising, top velocity) of a trapezoidal ramp over ``distance``."""
    t_acc = velocity / acceleration
    if acceleration * t_acc**2 > distance:  # never reaches cruise speed
        t_acc = math.sqrt(distance / acceleration)
        velocity = acceleration * t_acc
    cruise = (distance - acceleration * t_acc**2) / velocity if velocity > 0 else 0.0
    return t_acc, cruise, velocity


def ramp_profile(distance: float, velocity: float, acceleration: float, t) -> tuple[np.ndarray, float]:
    """An FRAMP move's trapezoidal ramp: (distance covered at time(s) ``t`` since it began, duration).

    Accelerates at ``acceleration`` to ``velocity``, cruises, decelerates; a move too short
    to reach ``velocity`` turns at half way. Times before the start cover 0, after the end
    ``distance``.
    """
    t_acc, cruise, velocity = _ramp_phases(distance, velocity, acceleration)
    total = 2 * t_acc + cruise
    t = np.clip(np.asarray(t, dtype=float), 0.0, total)
    rest = total - t
    covered = np.where(t < t_acc, 0.5 * acceleration * t**2,
                       np.where(t < t_acc + cruise, 0.5 * acceleration * t_acc**2 + velocity * (t - t_acc),
                                distance - 0.5 * acceleration * rest**2))
    return covered, total


def ramp_time(distance: float, velocity: float, acceleration: float, covered) -> np.ndarray:
    """Inverse of :func:`ramp_profile`: time(s) since the move began at which ``covered`` was covered.

    Examples
    --------
    >>> round(float(ramp_time(0.5, 0.5, 1.0, ramp_profile(0.5, 0.5, 1.0, 1.2)[0])), 9)
    1.2
    """
    t_acc, cruise, velocity = _ramp_phases(distance, velocity, acceleration)
    covered = np.clip(np.asarray(covered, dtype=float), 0.0, distance)
    ramp = 0.5 * acceleration * t_acc**2  # distance covered while accelerating, and while braking
    return np.where(covered < ramp, np.sqrt(2 * covered / acceleration),
                    np.where(covered < distance - ramp, t_acc + (covered - ramp) / velocity,
                             2 * t_acc + cruise - np.sqrt(2 * np.maximum(distance - covered, 0.0) / acceleration)))


def bcc(body: bytes) -> int:
    """libm5api block check: S = 16-bit sum of H0, H1 and data; BCC = (S + (S >> 8)) & 0xFF."""
    s = sum(body) & 0xFFFF
    return (s + (s >> 8)) & 0xFF


def _player_bcc(module_id: int, data: bytes) -> int:
    return (module_id + sum(data)) & 0xFF


def escape(body: bytes) -> bytes:
    """Escape 0x02, 0x03 and 0x10 as ``0x10, byte + 0x80``."""
    out = bytearray()
    for b in body:
        if b in _SPECIAL:
            out += bytes([DLE, b + 0x80])
        else:
            out.append(b)
    return bytes(out)


def _unescape(body: bytes) -> bytes:
    out = bytearray()
    it = iter(body)
    for b in it:
        if b == DLE:
            nxt = next(it, None)
            if nxt is None or nxt - 0x80 not in _SPECIAL:
                shown = "end of frame" if nxt is None else f"0x{nxt:02X}"
                raise PowerCubeProtocolError(f"escape 0x10 must be followed by 0x82/0x83/0x90; got {shown}")
            out.append(nxt - 0x80)
        else:
            out.append(b)
    return bytes(out)


def encode_frame(module_id: int, data: bytes, *, direction: int = TO_MODULE) -> bytes:
    """Build a complete, escaped frame with libm5api's BCC.

    Parameters
    ----------
    module_id : int
        1..31.
    data : bytes
        D0..Dn-1, 1..8 bytes (command byte first).
    direction : int
        TO_MODULE (0x04) for host -> module, FROM_MODULE (0x08) for replies.
    """
    if not isinstance(data, (bytes, bytearray)):
        raise TypeError(f"data must be bytes; got {type(data).__name__}")
    if not 1 <= module_id <= 31:
        raise ValueError(f"module_id must be in 1..31; got {module_id}")
    if not 1 <= len(data) <= MAX_DATA:
        raise ValueError(f"data must hold 1..{MAX_DATA} bytes; got {len(data)}")
    if direction not in (TO_MODULE, FROM_MODULE):
        raise ValueError(f"direction must be 0x04 or 0x08; got {direction!r}")
    h0 = direction | ((module_id >> 3) & 0x3)
    h1 = ((module_id & 0x7) << 5) | len(data)
    body = bytes([h0, h1]) + bytes(data)
    return bytes([STX]) + escape(body + bytes([bcc(body)])) + bytes([ETX])


@dataclass(frozen=True)
class Frame:
    """A decoded frame: direction (0x04/0x08), module id and data bytes."""

    direction: int
    module_id: int
    data: bytes

    @property
    def command(self) -> int:
        return self.data[0]


def decode_frame(frame: bytes, *, check_bcc: bool = True) -> Frame:
    """Decode one complete frame (STX .. ETX, still escaped).

    ``check_bcc`` accepts libm5api's or Player's BCC (sources disagree); False accepts any.

    Raises
    ------
    PowerCubeProtocolError
        On a wrong STX/ETX, escape, direction, length or BCC.
    """
    if not isinstance(frame, (bytes, bytearray, memoryview)):
        raise TypeError(f"frame must be bytes; got {type(frame).__name__}")
    frame = bytes(frame)
    if len(frame) < 5 or frame[0] != STX or frame[-1] != ETX:
        raise PowerCubeProtocolError(
            f"a frame is STX .. ETX with at least 5 bytes; got {frame[:12].hex(' ')} ({len(frame)} bytes)"
        )
    body = _unescape(frame[1:-1])
    if len(body) < 4:
        raise PowerCubeProtocolError(f"a frame holds H0, H1, data and BCC; got {len(body)} bytes")
    h0, h1, data, check = body[0], body[1], body[2:-1], body[-1]
    direction = h0 & 0xFC
    if direction not in (TO_MODULE, FROM_MODULE):
        raise PowerCubeProtocolError(f"H0 direction bits must be 0x04 or 0x08; got 0x{direction:02X}")
    n = h1 & 0x1F
    if n != len(data) or not 1 <= n <= MAX_DATA:
        raise PowerCubeProtocolError(f"H1 announces {n} data bytes; got {len(data)}")
    module_id = ((h0 & 0x3) << 3) | (h1 >> 5)
    if check_bcc and check not in (bcc(body[:-1]), _player_bcc(module_id, data)):
        raise PowerCubeProtocolError(f"BCC mismatch: expected 0x{bcc(body[:-1]):02X}; got 0x{check:02X}")
    return Frame(direction, module_id, bytes(data))


class FrameDecoder:
    """Incremental frame decoder that resynchronises on garbage.

    Unescaped 0x02 and 0x03 occur only as STX and ETX, so a frame is the bytes from
    the last STX to the next ETX; anything else is skipped. :meth:`frames` returns
    decoded frames and :class:`PowerCubeProtocolError` instances for rejected ones.
    """

    def __init__(self, *, check_bcc: bool = True):
        self.check_bcc = check_bcc
        self._buf = bytearray()

    def clear(self) -> None:
        self._buf.clear()

    @property
    def pending(self) -> bool:
        return STX in self._buf

    def feed(self, data: bytes) -> None:
        self._buf += data

    def frames(self) -> list:
        out = []
        buf = self._buf
        while True:
            start = buf.find(STX)
            if start < 0:
                buf.clear()
                break
            end = buf.find(ETX, start)
            if end < 0:
                del buf[:start]
                break
            restart = buf.rfind(STX, start, end)  # a lost ETX: the newest STX starts the frame
            frame = bytes(buf[restart : end + 1])
            del buf[: end + 1]
            try:
                out.append(decode_frame(frame, check_bcc=self.check_bcc))
            except PowerCubeProtocolError as err:
                out.append(err)
        return out


def pack_float(value: float) -> bytes:
    """float32 little-endian (the module's unit: rad, rad/s, rad/s^2)."""
    return struct.pack("<f", float(value))


def unpack_float(data: bytes) -> float:
    """The float32 little-endian in the 4 bytes ``data``; PowerCubeProtocolError for another length."""
    if len(data) != 4:
        raise PowerCubeProtocolError(f"a float32 needs 4 bytes; got {len(data)}")
    return struct.unpack("<f", bytes(data))[0]
