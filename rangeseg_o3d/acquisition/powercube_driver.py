"""Driver for a Schunk/Amtec PowerCube rotary module (M5 serial protocol) as a TiltUnit."""

from __future__ import annotations

import logging
import math
import struct
import time

from .errors import SILENT_REQUESTS, DeviceTimeout, PowerCubeProtocolError
from .powercube import CMD, FROM_MODULE, MOTION, PARAM, STATE, Frame, FrameDecoder, encode_frame, pack_float, unpack_float
from .tilt import TiltUnit
from .transport import open_transport, port_name, read_some

__all__ = ["PowerCube"]

log = logging.getLogger(__name__)


class PowerCube(TiltUnit):
    """A PowerCube rotary module used as the tilt axis.

    Parameters
    ----------
    port : str or transport
        Port name (pyserial, ``baudrate`` 8N1) or a transport object.
    module_id : int
        Bus id of the module, 1..31 (Player's PW70 driver uses 11 for tilt).
    timeout : float
        Seconds of complete silence before :class:`DeviceTimeout`.
    reply_timeout : float
        Seconds to wait for one reply before resending.
    attempts : int
        Sends per command before :class:`PowerCubeProtocolError`.
    poll_interval : float
        Pause between state polls while waiting for a move.
    """

    def __init__(self, port, *, module_id: int = 11, baudrate: int = 9600, timeout: float = 2.0,
                 reply_timeout: float = 0.2, attempts: int = 20, poll_interval: float = 0.01):
        if not 1 <= module_id <= 31:
            raise ValueError(f"module_id must be in 1..31; got {module_id}")
        if timeout <= 0 or reply_timeout <= 0:
            raise ValueError(f"timeouts must be positive; got timeout={timeout}, reply_timeout={reply_timeout}")
        self.transport = open_transport(port, baudrate=baudrate, timeout=reply_timeout)
        self.port = port if isinstance(port, str) else port_name(self.transport)
        self.module_id = module_id
        self.timeout = timeout
        self.reply_timeout = reply_timeout
        self.attempts = attempts
        self.poll_interval = poll_interval
        self.stats = {"sent": 0, "bad_frames": 0, "silent": 0}
        self._decoder = FrameDecoder()
        self._answered_sent_at = float("nan")  # host time the last answered request went out

    def close(self) -> None:
        close = getattr(self.transport, "close", None)
        if callable(close):
            close()

    # -- exchange ---------------------------------------------------------------
    def _await(self, echo: bytes, reply_timeout: float) -> tuple[Frame | None, bool]:
        start = time.monotonic()
        heard = False
        while (left := reply_timeout - (time.monotonic() - start)) > 0:
            data = read_some(self.transport, left)
            if not data:
                continue
            heard = True
            self._decoder.feed(data)
            for frame in self._decoder.frames():
                if isinstance(frame, PowerCubeProtocolError):
                    self.stats["bad_frames"] += 1
                elif (frame.direction == FROM_MODULE and frame.module_id == self.module_id
                      and frame.data[: len(echo)] == echo):
                    return frame, True
        return None, heard

    def request(self, data: bytes, echo: bytes | None = None) -> Frame:
        """Send ``data``; return the module's reply that starts with ``echo`` (default: D0 [, D1]).

        Raises
        ------
        DeviceTimeout
            Nothing came back for ``timeout`` seconds.
        PowerCubeProtocolError
            Only corrupted or foreign frames came back ``attempts`` times.
        """
        echo = bytes(data[:2] if data[0] in (CMD["get"], CMD["set"], CMD["motion"]) else data[:1]) \
            if echo is None else echo
        frame = encode_frame(self.module_id, bytes(data))
        silent_since = time.monotonic()
        silent_in_a_row = 0
        for _ in range(self.attempts):
            reset = getattr(self.transport, "reset_input_buffer", None)
            if callable(reset):
                reset()
            self._decoder.clear()
            self.transport.write(frame)
            sent_at = time.monotonic()
            self.stats["sent"] += 1
            reply, heard = self._await(echo, self.reply_timeout)
            if reply is not None:
                self._answered_sent_at = sent_at
                return reply
            if heard:
                silent_since = time.monotonic()
                silent_in_a_row = 0
            else:
                self.stats["silent"] += 1
                silent_in_a_row += 1
                # a garbled request goes unanswered too: silence alone is not a dead device
                if (time.monotonic() - silent_since >= self.timeout
                        and silent_in_a_row >= min(self.attempts, SILENT_REQUESTS)):
                    raise DeviceTimeout(self.port, self.timeout, "PowerCube")
        raise PowerCubeProtocolError(
            f"no valid reply to {bytes(data[:2]).hex(' ')} from PowerCube {self.module_id} on {self.port} "
            f"after {self.attempts} attempts"
        )

    # -- parameters -------------------------------------------------------------
    def get_param(self, name: str) -> bytes:
        code = PARAM[name]
        reply = self.request(bytes([CMD["get"], code]))
        if len(reply.data) < 6:
            raise PowerCubeProtocolError(f"get {name}: expected 4 value bytes; got {reply.data.hex(' ')}")
        return reply.data[2:6]

    def set_float(self, name: str, value: float, *, verify: bool = True) -> None:
        """Set a float parameter; with ``verify`` read it back until it holds the value sent.

        The module may not check the BCC, so a corrupted set could store a wrong value.
        """
        if not math.isfinite(value):
            raise ValueError(f"{name} must be finite; got {value}")
        wanted = pack_float(value)
        for _ in range(self.attempts):
            self.request(bytes([CMD["set"], PARAM[name]]) + wanted)
            if not verify or self.get_param(name) == wanted:
                return
        raise PowerCubeProtocolError(f"PowerCube on {self.port} does not keep {name} = {value}")

    def state(self) -> int:
        """The u32 state word (bits in :data:`~rangeseg_o3d.acquisition.powercube.STATE`)."""
        return struct.unpack("<I", self.get_param("state"))[0]

    def read_position(self) -> float:
        value = unpack_float(self.get_param("position"))
        if not math.isfinite(value):
            raise PowerCubeProtocolError(f"position reply is not a finite number: {value}")
        return value

    def timed_position(self) -> tuple[float, float]:
        """(host time the position request went out, actual position in rad) of a moving unit.

        The module reads its angle when the request reaches it, so the time the request left
        dates the angle, however late the host gets to the reply.
        """
        value = self.read_position()
        return self._answered_sent_at, value

    def position(self, *, confirmations: int = 2) -> float:
        """Actual position (rad): read until ``confirmations`` reads in a row agree.

        A stationary module returns the same float32 every time, so agreement guards
        against a corrupted reply that slipped through the 8-bit BCC.
        """
        previous = None
        agree = 1
        for _ in range(self.attempts):
            value = self.read_position()
            agree = agree + 1 if value == previous else 1
            if agree >= confirmations:
                return value
            previous = value
        raise PowerCubeProtocolError(f"position of PowerCube on {self.port} does not settle: last {previous}")

    # -- commands ---------------------------------------------------------------
    def reset(self) -> None:
        """Clear an error state."""
        self.request(bytes([CMD["reset"]]))

    def home(self) -> None:
        self.request(bytes([CMD["home"]]))

    def halt(self) -> None:
        self.request(bytes([CMD["halt"]]))

    def set_ramp(self, velocity: float, acceleration: float) -> None:
        """Ramp velocity (rad/s) and acceleration (rad/s^2) for FRAMP moves."""
        if not (velocity > 0 and acceleration > 0):
            raise ValueError(f"velocity and acceleration must be positive; got {velocity}, {acceleration}")
        self.set_float("ramp_velocity", velocity)
        self.set_float("ramp_acceleration", acceleration)

    def move_to(self, angle: float) -> None:
        """Start an FRAMP move to ``angle`` (rad)."""
        if not math.isfinite(angle):
            raise ValueError(f"angle must be finite; got {angle}")
        self.request(bytes([CMD["motion"], MOTION["framp"]]) + pack_float(angle))

    def _wait_state(self, done, what: str, timeout: float) -> int:
        deadline = time.monotonic() + timeout
        while True:
            state = self.state()
            if state & (STATE["error"] | STATE["power_fault"] | STATE["tow_error"]):
                raise PowerCubeProtocolError(f"PowerCube on {self.port} reports error state 0x{state:08X}")
            if done(state):
                return state
            if time.monotonic() > deadline:
                raise DeviceTimeout(self.port, timeout, f"PowerCube ({what} not finished)")
            time.sleep(self.poll_interval)

    def wait_until_stopped(self, timeout: float) -> None:
        """Poll the state until MOTION clears."""
        self._wait_state(lambda s: not s & STATE["motion"], "move", timeout)

    def initialise(self, *, velocity: float, acceleration: float, timeout: float) -> None:
        """Reset, home, wait until homed and at ramp end, set the ramp."""
        self.reset()
        self.home()
        self._wait_state(lambda s: s & STATE["homed"] and not s & STATE["motion"], "homing", timeout)
        self.set_ramp(velocity, acceleration)
