"""Run a virtual serial device on a pseudo-terminal, in a thread.

The host opens :attr:`PtyDevice.port` (the slave path) with pyserial, so the real
serial code path runs. The device sees only what arrives at its own baud rate: the
host's rate is read from the slave's termios, and bytes sent at a different rate
arrive as garbage (the device ignores host bytes sent at the wrong rate).
"""

from __future__ import annotations

import logging
import os
import select
import termios
import threading
import tty
from dataclasses import dataclass

from .faults import LineFaults

__all__ = ["Output", "PtyDevice"]

log = logging.getLogger(__name__)

_SPEEDS = {getattr(termios, f"B{rate}"): rate for rate in (9600, 19200, 38400, 57600, 115200, 500000)
           if hasattr(termios, f"B{rate}")}


@dataclass(frozen=True)
class Output:
    """Bytes a device sends after ``delay`` simulated seconds, at line rate ``baud``."""

    delay: float
    data: bytes
    baud: int


class PtyDevice:
    """A device object (``baudrate``, ``handle(bytes) -> [Output]``, ``tick() -> [Output]``,
    ``clock``) served on a fresh pseudo-terminal by a daemon thread.

    Parameters
    ----------
    device : object
        The virtual device.
    faults : LineFaults, optional
        Applied to both directions.
    """

    def __init__(self, device, faults: LineFaults | None = None):
        self.device = device
        self.faults = faults or LineFaults(0.0)
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self.port = os.ttyname(self._slave)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name=f"sim-{type(device).__name__}", daemon=True)
        self.error: BaseException | None = None

    def start(self) -> "PtyDevice":
        self._thread.start()
        return self

    def host_baud(self) -> int | None:
        try:
            return _SPEEDS.get(termios.tcgetattr(self._slave)[5])
        except termios.error:
            return None

    def _send(self, out: Output) -> None:
        self.device.clock.sleep(out.delay)
        data = self.faults.apply(out.data)
        if self.host_baud() != out.baud:
            data = self.faults.garbage(len(data))
        try:
            os.write(self._master, data)
        except (BlockingIOError, OSError):
            pass  # nobody reads the line: the bytes are lost, as on a real wire

    def _serve(self) -> None:
        try:
            while not self._stop.is_set():
                ready, _, _ = select.select([self._master], [], [], 0.002)
                outputs = []
                if ready:
                    try:
                        data = os.read(self._master, 4096)
                    except (BlockingIOError, OSError):
                        data = b""
                    data = self.faults.apply(data)
                    if data and self.host_baud() == self.device.baudrate:
                        outputs = self.device.handle(data)
                outputs = list(outputs) + list(self.device.tick())
                for out in outputs:
                    if self._stop.is_set():
                        break
                    self._send(out)
        except BaseException as err:  # surfaced by stop(); a dead simulator must not hang tests silently
            self.error = err
            log.exception("simulator thread failed")

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5)
        for fd in (self._master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass
        if self.error is not None:
            raise RuntimeError(f"simulator {type(self.device).__name__} failed") from self.error

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()
