"""Fixtures for the acquisition tests: a scripted transport and a flat-wall stand-in scene."""

import time

import numpy as np
import pytest

from rangeseg_o3d.kinematics import NoddingGeometry, nodding_rays

WALL_X = 3.0
MOUNT = (0.0, 0.0, 0.1)


class ScriptedTransport:
    """A fake serial port: each write must equal the next scripted request; its reply is queued.

    ``script`` is a list of ``(expected_write, reply_bytes)``; ``reply_bytes`` may be b""
    (silence). :meth:`verify` asserts that every exchange happened.
    """

    def __init__(self, script, *, port="scripted", baudrate=9600):
        self.script = list(script)
        self.port = port
        self.baudrate = baudrate
        self.timeout = 0.0
        self.writes = []
        self.baud_at_write = []
        self._rx = bytearray()

    @property
    def in_waiting(self):
        return len(self._rx)

    def reset_input_buffer(self):
        self._rx.clear()

    def write(self, data):
        data = bytes(data)
        self.writes.append(data)
        self.baud_at_write.append(self.baudrate)
        assert self.script, f"unexpected write {data.hex(' ')}: script exhausted"
        expected, reply = self.script.pop(0)
        assert data == expected, f"expected {expected.hex(' ')}, got {data.hex(' ')}"
        self._rx += reply
        return len(data)

    def read(self, n=1):
        if not self._rx:
            time.sleep(min(self.timeout or 0.0, 0.005))
            return b""
        out = bytes(self._rx[:n])
        del self._rx[:n]
        return out

    def close(self):
        pass

    def verify(self):
        assert not self.script, f"{len(self.script)} scripted exchanges never happened"


@pytest.fixture
def scripted():
    made = []

    def make(script, **kw):
        t = ScriptedTransport(script, **kw)
        made.append(t)
        return t

    yield make
    for t in made:
        t.verify()


def wall_ranges(tilt, beams, *, mount=MOUNT, tilt_sign=1.0, wall_x=WALL_X):
    """Exact ranges to the plane x = wall_x (inf where a beam misses it)."""
    o, d = nodding_rays(NoddingGeometry(beams, np.array([tilt]), mount, tilt_sign))
    o, d = o[0], d[0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (wall_x - o[:, 0]) / d[:, 0]
    return np.where(np.isfinite(t) & (t > 0), t, np.inf)


@pytest.fixture
def wall():
    return wall_ranges
