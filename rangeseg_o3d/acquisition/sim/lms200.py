"""A virtual SICK LMS200 speaking the LMS2xx telegram protocol, ranges from the synthetic ray caster."""

from __future__ import annotations

import math
import struct

import numpy as np

from ..lms2xx import (
    ACK,
    BAUD_MODES,
    MODE_INSTALLATION,
    MODE_ON_REQUEST,
    MODE_STREAM,
    NAK,
    PASSWORD,
    SCAN_PERIOD,
    BadFrame,
    Telegram,
    TelegramDecoder,
    beam_angles,
    encode_scan_values,
    encode_telegram,
    scan_count,
)
from .clock import SimClock
from .pty import Output

__all__ = ["VirtualLms200", "beam_angles", "MAX_RANGE_MM", "SCAN_PERIOD"]

MAX_RANGE_MM = 8.183
_STATUS = 0x10
_TYPE = b"LMS200;30106"
_BAUD_OF_MODE = {mode: baud for baud, mode in BAUD_MODES.items()}
_REPLY_ADDRESS = 0x80
_INPUT_GAP = 0.1  # simulated seconds of silence that end a partial request


class VirtualLms200:
    """LMS200 state machine: modes, baud rates, variants, units, scans on request or streamed.

    Parameters
    ----------
    clock : SimClock
    scene : rangeseg_o3d.synthetic.Scene, optional
        Scanned with the synthetic LMS200 row model (exact ray casting, mixed pixels).
    row_ranges : callable, optional
        Instead of ``scene``: ``row_ranges(tilt, beam_angles) -> ranges (W,)`` metres,
        NaN or inf for no return.
    tilt_at : callable
        ``tilt_at(t) -> angle`` of the tilt unit (rad, unit convention) at simulated time t.
    mount_offset, tilt_sign
        Where the scanner sits on the tilt unit (see :mod:`rangeseg_o3d.geometry`).
    noise : float
        Range noise sigma in metres, reproducible per (tilt angle, beam).
    nak_rate : float
        Probability of answering a valid request with NAK.
    reset_after_scans : int, optional
        Power-cycle (power-on telegram at 9600 baud, defaults restored) on this scan request.
    silent : bool
        Answer nothing.
    silent_after_scans : int, optional
        Fall silent for good (unplugged) on this scan request.
    seed : int
    """

    def __init__(self, clock: SimClock, scene=None, *, row_ranges=None, tilt_at, mount_offset=(0.0, 0.0, 0.0), tilt_sign=1.0,
                 noise: float = 0.0, nak_rate: float = 0.0, reset_after_scans: int | None = None,
                 silent: bool = False, silent_after_scans: int | None = None, seed: int = 0):
        self.clock = clock
        if (scene is None) == (row_ranges is None):
            raise ValueError("give exactly one of scene and row_ranges")
        self.scene = scene
        self.row_ranges = row_ranges
        self.tilt_at = tilt_at
        self.mount_offset = np.asarray(mount_offset, dtype=float)
        self.tilt_sign = float(tilt_sign)
        self.noise = float(noise)
        self.nak_rate = float(nak_rate)
        self.reset_after_scans = reset_after_scans
        self.silent = silent
        self.silent_after_scans = silent_after_scans
        self.seed = seed
        self.rng = np.random.default_rng(seed)
        self.config = bytearray(34)  # EEPROM: survives a power cycle; units byte 6 = 0 (cm)
        self.scan_requests = 0
        self.streamed = 0  # scans sent in streaming mode
        self.resets = 0
        self._decoder = TelegramDecoder(replies=False)
        self._last_input = 0.0
        self._scan_cache: dict = {}
        self._power_on()

    def _power_on(self) -> None:
        self.baudrate = 9600
        self.mode = MODE_ON_REQUEST
        self.variant = (180, 100)
        self._next_stream = 0.0

    # -- measurement ----------------------------------------------------------------
    @property
    def unit(self) -> float:
        return 0.001 if self.config[6] == 1 else 0.01

    def ranges_at(self, tilt: float) -> np.ndarray:
        """Exact (plus reproducible noise) ranges of one scan line at unit angle ``tilt``."""
        beams = beam_angles(*self.variant)
        max_range = MAX_RANGE_MM if self.unit == 0.001 else 81.83
        # Noise seeded by the angle's bits: a re-read row gives the same ranges.
        key = struct.unpack("<Q", struct.pack("<d", float(tilt)))[0] ^ self.seed
        if self.row_ranges is not None:
            ranges = np.asarray(self.row_ranges(float(tilt), beams), dtype=float)
            if self.noise > 0:
                ranges = ranges + np.random.default_rng(key).normal(0.0, self.noise, ranges.shape)
        else:
            from ...synthetic.lms200 import lms200_row_ranges

            ranges = lms200_row_ranges(
                self.scene, float(tilt), beams, mount_offset=self.mount_offset, tilt_sign=self.tilt_sign,
                noise_sigma=self.noise, max_range=max_range + 1.0, seed=key,
            )
        return np.where(np.isfinite(ranges) & (ranges > max_range), max_range + 1.0, ranges)

    def _scan_telegram(self, tilt: float) -> bytes:
        # Ranges are a pure function of (tilt, variant, unit): re-reads of a row reuse them.
        key = (float(tilt), self.variant, self.unit)
        frame = self._scan_cache.get(key)
        if frame is None:
            payload = encode_scan_values(self.ranges_at(tilt), unit=self.unit, status=_STATUS)
            frame = encode_telegram(payload, _REPLY_ADDRESS)
            if len(self._scan_cache) > 256:
                self._scan_cache.clear()
            self._scan_cache[key] = frame
        return frame

    # -- protocol -------------------------------------------------------------------
    def _reply(self, payload: bytes, delay: float = 0.0) -> list[Output]:
        frame = encode_telegram(payload + bytes([_STATUS]), _REPLY_ADDRESS)
        return [Output(delay + len(frame) * 10 / self.baudrate, frame, self.baudrate)]

    def _mode_change(self, data: bytes) -> list[Output]:
        mode = data[0] if data else None
        if mode == MODE_INSTALLATION:
            ok = data[1:9] == PASSWORD
            if ok:
                self.mode = mode
            return self._reply(bytes([0xA0, 0 if ok else 1]))
        if mode in _BAUD_OF_MODE:
            out = self._reply(bytes([0xA0, 0]))  # confirmed at the old rate
            self.baudrate = _BAUD_OF_MODE[mode]
            return out
        if mode in (MODE_STREAM, MODE_ON_REQUEST):
            self.mode = mode
            self._next_stream = self.clock.now() + SCAN_PERIOD
            return self._reply(bytes([0xA0, 0]), 0.01)
        return self._reply(bytes([0xA0, 1]))

    def _variant(self, data: bytes) -> list[Output]:
        if len(data) != 4:
            return self._reply(b"\x92\x00")
        fov, res = data[0] | data[1] << 8, data[2] | data[3] << 8
        ok = (fov, res) in ((180, 100), (180, 50), (100, 100), (100, 50), (100, 25))
        if ok:
            self.variant = (fov, res)
        return self._reply(bytes([0xBB, int(ok)]) + data)

    def _power_cycle(self) -> list[Output]:
        self.resets += 1
        self._power_on()
        frame = encode_telegram(b"\x90" + _TYPE + bytes([_STATUS]), _REPLY_ADDRESS)
        return [Output(0.5, frame, 9600)]

    def _answer(self, t: Telegram) -> list[Output]:
        cmd, data = t.command, t.data
        if cmd == 0x30 and data[:1] == b"\x01":
            self.scan_requests += 1
            if self.silent_after_scans is not None and self.scan_requests >= self.silent_after_scans:
                self.silent = True
                return []
            if self.reset_after_scans is not None and self.scan_requests == self.reset_after_scans:
                return self._power_cycle()
            now = self.clock.now()
            start = (math.floor(now / SCAN_PERIOD) + 1) * SCAN_PERIOD  # next full revolution
            frame = self._scan_telegram(self.tilt_at(start + SCAN_PERIOD / 2))
            wait = start + SCAN_PERIOD - now
            return [Output(wait + len(frame) * 10 / self.baudrate, frame, self.baudrate)]
        if cmd == 0x20:
            return self._mode_change(data)
        if cmd == 0x3B:
            return self._variant(data)
        if cmd == 0x3A:
            return self._reply(b"\xBA" + _TYPE)
        if cmd == 0x31:
            return self._reply(b"\xB1" + _TYPE + bytes(20))
        if cmd == 0x74:
            return self._reply(b"\xF4" + bytes(self.config))
        if cmd == 0x77 and self.mode == MODE_INSTALLATION and len(data) in (32, 34):
            self.config[: len(data)] = data
            return self._reply(b"\xF7\x01" + bytes(self.config), 0.5)
        if cmd == 0x10:
            out = self._reply(b"\x91")
            self._power_on()
            return out
        return self._reply(b"\x92" + bytes([cmd]))

    def handle(self, data: bytes) -> list[Output]:
        now = self.clock.now()
        if now - self._last_input > _INPUT_GAP:
            self._decoder.clear()  # like the device's inter-character timeout: drop a stale partial frame
        self._last_input = now
        self._decoder.feed(data)
        outputs: list[Output] = []
        for event in self._decoder.events():
            if self.silent:
                continue
            if isinstance(event, BadFrame):
                outputs.append(Output(10 / self.baudrate, bytes([NAK]), self.baudrate))
                continue
            if not isinstance(event, Telegram):
                continue
            if self.nak_rate and self.rng.random() < self.nak_rate:
                outputs.append(Output(10 / self.baudrate, bytes([NAK]), self.baudrate))
                continue
            outputs.append(Output(10 / self.baudrate, bytes([ACK]), self.baudrate))
            outputs.extend(self._answer(event))
        return outputs

    def tick(self) -> list[Output]:
        """In streaming mode, the next scan once the line is free.

        Scans keep the device's own beat, one per mirror revolution or per transfer when
        the line is slower: a scan due at ``start`` was measured over the revolution before
        it and its last byte leaves ``start`` + transfer, however late this thread runs
        (the simulator's own delays must not slow the stream down). A simulator a whole
        scan behind starts a new beat.
        """
        if self.mode != MODE_STREAM or self.silent:
            return []
        now = self.clock.now()
        if now < self._next_stream:
            return []
        transfer = (2 * scan_count(*self.variant) + 10) * 10 / self.baudrate
        beat = max(SCAN_PERIOD, transfer)
        start = self._next_stream if now - self._next_stream < beat else now
        frame = self._scan_telegram(self.tilt_at(start - SCAN_PERIOD / 2))
        self._next_stream = start + beat
        self.streamed += 1
        return [Output(max(start + transfer - now, 0.0), frame, self.baudrate)]
