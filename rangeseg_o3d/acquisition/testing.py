"""Protocol test helpers, shipped with the package (as pymeasure's ``expected_protocol``).

A driver is tested without hardware by giving it a :class:`ScriptedTransport`: a fake
serial port holding the exact bytes the driver must write, each with the reply the device
would send. A write that differs from the next scripted one fails at once, naming both;
:meth:`ScriptedTransport.verify` fails if an exchange never happened.
:func:`expected_protocol` wraps both in a ``with`` block:

>>> from rangeseg_o3d.acquisition import Lms2xx
>>> from rangeseg_o3d.acquisition.lms2xx import encode_telegram
>>> status = encode_telegram(b"\\x31")
>>> reply = b"\\x06" + encode_telegram(b"\\xb1\\x00\\x10", 0x80)   # ACK, then the status reply
>>> with expected_protocol(Lms2xx, [(status, reply)], timeout=0.3, settle=0.0) as lms:
...     telegram = lms.status()

Third-party drivers built on :func:`rangeseg_o3d.acquisition.transport.open_transport`
(any object with ``read`` and ``write``) can be tested the same way.
"""

from __future__ import annotations

import time
from contextlib import contextmanager

__all__ = ["ProtocolMismatch", "ScriptedTransport", "expected_protocol"]


class ProtocolMismatch(AssertionError):
    """The driver wrote something other than the script expected, or left exchanges unused."""


def _hex(data: bytes) -> str:
    return data.hex(" ") if data else "(nothing)"


class ScriptedTransport:
    """A fake serial port: each write must equal the next scripted request; its reply is queued.

    Parameters
    ----------
    script : iterable of (bytes, bytes)
        ``(expected_write, reply)`` pairs in order; ``reply`` may be ``b""`` (the device
        stays silent).
    port : str
        Name the driver reports in its errors.
    baudrate : int
        The port's initial rate; :attr:`baud_at_write` records the rate of every write.

    ``writes`` lists every write; ``script`` holds the exchanges not yet used.
    """

    def __init__(self, script, *, port: str = "scripted", baudrate: int = 9600):
        self.script = [(bytes(request), bytes(reply)) for request, reply in script]
        self.port = port
        self.baudrate = baudrate
        self.timeout = 0.0
        self.writes: list[bytes] = []
        self.baud_at_write: list[int] = []
        self._rx = bytearray()

    @property
    def in_waiting(self) -> int:
        """Bytes of queued replies not read yet."""
        return len(self._rx)

    def reset_input_buffer(self) -> None:
        self._rx.clear()

    def write(self, data) -> int:
        """Check ``data`` against the next scripted request and queue its reply."""
        data = bytes(data)
        self.writes.append(data)
        self.baud_at_write.append(self.baudrate)
        if not self.script:
            raise ProtocolMismatch(f"{self.port}: unexpected write {_hex(data)}: the script is exhausted")
        expected, reply = self.script.pop(0)
        if data != expected:
            raise ProtocolMismatch(f"{self.port}: write {len(self.writes)} expected {_hex(expected)}, "
                                   f"got {_hex(data)}")
        self._rx += reply
        return len(data)

    def read(self, size: int = 1) -> bytes:
        """Up to ``size`` queued reply bytes; b"" (after a short wait) when none are queued."""
        if not self._rx:
            time.sleep(min(self.timeout or 0.0, 0.005))
            return b""
        out = bytes(self._rx[:size])
        del self._rx[:size]
        return out

    def close(self) -> None:
        pass

    def verify(self) -> None:
        """Raise ProtocolMismatch if a scripted exchange never happened."""
        if self.script:
            pending = ", ".join(_hex(request) for request, _ in self.script[:3])
            raise ProtocolMismatch(f"{self.port}: {len(self.script)} scripted exchange(s) never happened "
                                   f"(next expected write: {pending})")


@contextmanager
def expected_protocol(driver_class, script, *, port: str = "scripted", baudrate: int = 9600, **driver_kwargs):
    """A driver on a :class:`ScriptedTransport`; on leaving the block, every exchange must have happened.

    ``driver_class(transport, **driver_kwargs)`` builds the driver (its first argument is
    the port). ``baudrate`` is the scripted port's initial rate. Leaving the block by an
    exception skips the final check, so the exception is what the test sees.
    """
    transport = ScriptedTransport(script, port=port, baudrate=baudrate)
    driver = driver_class(transport, **driver_kwargs)
    yield driver
    transport.verify()
