"""Fixtures for the acquisition tests: a scripted transport and a flat-wall stand-in scene."""

import time

import pytest

from acquisition_helpers import wall_ranges

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


@pytest.fixture
def wall():
    return wall_ranges
