"""A virtual PowerCube rotary module speaking the M5 serial protocol."""

from __future__ import annotations

import math
import struct

import numpy as np

from ..powercube import (CMD, FROM_MODULE, MOTION, PARAM, STATE, Frame, FrameDecoder, encode_frame, pack_float,
                         ramp_profile)
from .clock import SimClock
from .pty import Output

__all__ = ["VirtualPowerCube", "ramp_profile"]

_LIMIT = math.pi / 2


def _f32(value: float) -> float:
    return float(np.float32(value))


class VirtualPowerCube:
    """A PowerCube module: FRAMP moves with a trapezoidal profile in simulated time.

    Parameters
    ----------
    clock : SimClock
    module_id : int
    baudrate : int
        Line rate the module talks at.
    start_position : float
        Angle at power-on (rad); homing drives to 0.
    silent : bool
        Answer nothing (an unplugged module).
    """

    def __init__(self, clock: SimClock, *, module_id: int = 11, baudrate: int = 9600,
                 start_position: float = 0.05, silent: bool = False):
        self.clock = clock
        self.module_id = module_id
        self.baudrate = baudrate
        self.silent = silent
        self.params = {PARAM["ramp_velocity"]: 0.5, PARAM["ramp_acceleration"]: 1.0,
                       PARAM["max_velocity"]: 2.0, PARAM["max_acceleration"]: 8.0,
                       PARAM["min_position"]: -_LIMIT, PARAM["max_position"]: _LIMIT}
        self.homed = False
        self.halted = False
        self._homing = False
        self._move = (_f32(start_position), _f32(start_position), 0.0, 1.0, 1.0)
        self._decoder = FrameDecoder(check_bcc=False)  # the module may not check the BCC
        self.commands: list[int] = []

    # -- kinematics -------------------------------------------------------------
    def position_at(self, t: float) -> float:
        start, target, t0, velocity, acceleration = self._move
        if start == target:
            return target
        covered, total = ramp_profile(abs(target - start), velocity, acceleration, t - t0)
        if t - t0 >= total:
            return target
        return start + math.copysign(float(covered), target - start)

    def moving_at(self, t: float) -> bool:
        start, target, t0, velocity, acceleration = self._move
        return start != target and t - t0 < ramp_profile(abs(target - start), velocity, acceleration, 0.0)[1]

    def position(self) -> float:
        return self.position_at(self.clock.now())

    def _start_move(self, target: float) -> None:
        now = self.clock.now()
        lo, hi = self.params[PARAM["min_position"]], self.params[PARAM["max_position"]]
        target = _f32(min(max(target, lo), hi))
        self._move = (_f32(self.position_at(now)), target, now,
                      self.params[PARAM["ramp_velocity"]], self.params[PARAM["ramp_acceleration"]])
        self.halted = False

    def state_word(self) -> int:
        now = self.clock.now()
        if self._homing and not self.moving_at(now):
            self._homing, self.homed = False, True
        state = (STATE["homed"] if self.homed else 0) | (STATE["halted"] if self.halted else 0)
        return state | (STATE["motion"] if self.moving_at(now) else STATE["ramp_end"])

    # -- protocol ---------------------------------------------------------------
    def _value(self, param: int) -> bytes:
        if param == PARAM["state"]:
            return struct.pack("<I", self.state_word())
        if param == PARAM["position"]:
            return pack_float(self.position())
        if param == PARAM["velocity"]:
            return pack_float(0.0)
        return pack_float(self.params.get(param, 0.0))

    def _set(self, param: int, raw: bytes) -> None:
        if len(raw) != 4 or param not in self.params:
            return
        value = struct.unpack("<f", raw)[0]
        if not math.isfinite(value):
            return
        if param == PARAM["ramp_velocity"]:
            value = min(max(value, 1e-3), self.params[PARAM["max_velocity"]])
        elif param == PARAM["ramp_acceleration"]:
            value = min(max(value, 1e-3), self.params[PARAM["max_acceleration"]])
        self.params[param] = _f32(value)

    def _answer(self, frame: Frame) -> bytes | None:
        d = frame.data
        cmd = d[0]
        self.commands.append(cmd)
        if cmd == CMD["reset"]:
            reply = d[:1]
        elif cmd == CMD["home"]:
            self._start_move(0.0)
            self._homing = True
            reply = d[:1]
        elif cmd == CMD["halt"]:
            now = self.clock.now()
            p = _f32(self.position_at(now))
            self._move = (p, p, now, 1.0, 1.0)
            self.halted = True
            reply = d[:1]
        elif cmd == CMD["set"] and len(d) >= 2:
            self._set(d[1], d[2:6])
            reply = d[:2]
        elif cmd == CMD["get"] and len(d) >= 2:
            reply = d[:2] + self._value(d[1])
        elif cmd == CMD["motion"] and len(d) >= 6 and d[1] in (MOTION["framp"], MOTION["framp_ext"]):
            self._start_move(struct.unpack("<f", d[2:6])[0])
            if d[1] == MOTION["framp_ext"]:
                short = (0x10 if self.moving_at(self.clock.now()) else 0x20) | (0x02 if self.homed else 0)
                reply = bytes([CMD["motion"], d[1]]) + pack_float(self.position()) + bytes([short, 0])
            else:
                reply = d[:2]
        else:
            return None
        return encode_frame(self.module_id, bytes(reply), direction=FROM_MODULE)

    def handle(self, data: bytes) -> list[Output]:
        self._decoder.feed(data)
        outputs = []
        for frame in self._decoder.frames():
            if isinstance(frame, Exception) or frame.module_id != self.module_id or frame.direction == FROM_MODULE:
                continue
            reply = self._answer(frame)
            if reply is not None and not self.silent:
                outputs.append(Output(0.001 + len(reply) * 10 / self.baudrate, reply, self.baudrate))
        return outputs

    def tick(self) -> list[Output]:
        return []
