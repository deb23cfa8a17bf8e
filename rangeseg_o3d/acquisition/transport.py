"""Serial transports: open a port by name, or accept any object that behaves like serial.Serial."""

from __future__ import annotations

import math
import queue
import select
import threading
import time

from .errors import AcquisitionError
from .logged_transport import LoggedTransport, port_name

__all__ = ["open_transport", "port_name", "read_some", "ChunkReader"]

_REQUIRED = ("read", "write")


def open_transport(port, *, baudrate: int, timeout: float = 0.05):
    """Return a transport for ``port``.

    Parameters
    ----------
    port : str or transport
        A device path / pyserial URL (``"/dev/ttyUSB0"``, ``"loop://"``), opened with
        pyserial at ``baudrate`` 8N1; or an object with ``read``, ``write``,
        ``timeout`` and ``baudrate`` (``serial.Serial``, a scripted fake), used as is.

    Raises
    ------
    TypeError
        If ``port`` is neither a string nor a transport-like object.

    Either way the transport comes wrapped in a
    :class:`~rangeseg_o3d.acquisition.logged_transport.LoggedTransport`: every write and
    every read that returned bytes is logged at DEBUG level.
    """
    if isinstance(port, str):
        import serial  # only drivers that open real ports need pyserial

        return LoggedTransport(serial.serial_for_url(port, baudrate=baudrate, timeout=timeout), name=port)
    missing = [name for name in _REQUIRED if not callable(getattr(port, name, None))]
    if missing:
        raise TypeError(
            "port must be a port name (str) or a transport with read/write/timeout/baudrate; "
            f"got {type(port).__name__} without {', '.join(missing)}"
        )
    return LoggedTransport(port)


def _descriptor(transport) -> int | None:
    """The file descriptor of a port that has one (pyserial on POSIX), else None."""
    fileno = getattr(transport, "fileno", None)
    if not callable(fileno) or not hasattr(transport, "in_waiting"):
        return None
    try:
        return int(fileno())
    except (OSError, ValueError, TypeError, AttributeError):
        return None


def read_some(transport, wait: float) -> bytes:
    """Everything that arrives within ``wait`` seconds after the first byte; b"" if nothing.

    Blocks at most ``wait`` seconds for the first byte, then takes what is buffered.
    A port with a file descriptor is waited on with ``select``: changing pyserial's
    ``timeout`` reconfigures the port (tcsetattr) on every call, which at hundreds of
    reads per second costs more than the bytes.
    """
    wait = max(0.0, float(wait))
    descriptor = _descriptor(transport)
    if descriptor is not None:
        if not transport.in_waiting:
            ready, _, _ = select.select([descriptor], [], [], wait)
            if not ready:
                return b""
        waiting = transport.in_waiting
        return bytes(transport.read(waiting)) if waiting else b""
    if getattr(transport, "timeout", None) != wait:
        transport.timeout = wait
    waiting = getattr(transport, "in_waiting", 0) or 0
    data = transport.read(max(1, waiting))
    if data:
        more = getattr(transport, "in_waiting", 0) or 0
        if more:
            data += transport.read(more)
    return bytes(data)


_ENDED = object()  # the reader thread's last item: no chunk will follow


class ChunkReader:
    """Reads a port in a thread, each chunk with the host time it arrived.

    A host that is busy elsewhere (a slow query to another device, a loaded machine) would
    otherwise read late what arrived early, and date it late. The thread waits in
    :func:`read_some` (``select`` releases the interpreter), so it takes bytes as they come.
    Nothing else may read the port while the reader runs. Every wait on the thread is
    bounded: :meth:`take` returns once it has ended, :meth:`stop` gives up on a thread
    stuck in a read.

    Parameters
    ----------
    transport : transport
        The port to read (as :func:`open_transport` returns it).
    wait : float
        Longest single wait for bytes, in seconds: how soon :meth:`stop` takes effect.
    """

    def __init__(self, transport, wait: float = 0.005):
        if not wait > 0:
            raise ValueError(f"wait must be positive; got {wait}")
        self._transport = transport
        self._wait = float(wait)
        self._chunks: queue.SimpleQueue = queue.SimpleQueue()
        self._stop = threading.Event()
        self._ended = False  # take() has met _ENDED
        self.error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name=f"reader-{port_name(transport)}", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                data = read_some(self._transport, self._wait)
                if data:
                    self._chunks.put((time.monotonic(), data))
        except BaseException as err:  # a port that went away: raised to the caller by take()
            self.error = err
        finally:
            self._chunks.put(_ENDED)  # a take() waiting for chunks returns at once

    def take(self, wait: float = 0.0) -> list[tuple[float, bytes]]:
        """Every ``(arrival time, bytes)`` chunk not taken yet, oldest first, waiting up to
        ``wait`` seconds for the first, or less if the thread ends; raises what stopped the
        thread once its chunks are taken."""
        if not math.isfinite(wait):
            raise ValueError(f"wait must be a finite number of seconds; got {wait}")
        chunks = []
        try:
            item = self._chunks.get(timeout=wait) if wait > 0 and not self._ended else self._chunks.get_nowait()
            while True:
                if item is _ENDED:
                    self._ended = True
                else:
                    chunks.append(item)
                item = self._chunks.get_nowait()
        except queue.Empty:
            pass
        if not chunks and self.error is not None:
            raise self.error
        return chunks

    def stop(self, timeout: float = 2.0) -> None:
        """End the thread (within ``wait`` of the port's read); chunks not taken yet stay for :meth:`take`.

        Raises
        ------
        AcquisitionError
            The thread is still in a read ``timeout`` seconds after the ``wait`` its last read
            may take (a port whose read ignores its timeout); it is left behind (a daemon) and
            the port should be closed.
        """
        self._stop.set()
        # (a read that began just before the stop may take its whole wait: a reader made with a
        # wait longer than ``timeout`` is not stuck for that)
        self._thread.join(self._wait + timeout)
        if self._thread.is_alive():
            raise AcquisitionError(f"the thread reading {port_name(self._transport)} did not stop within "
                                   f"{timeout:.3g} s past its {self._wait:.3g} s wait: the port's read blocks "
                                   "beyond that wait")

    @property
    def running(self) -> bool:
        return self._thread.is_alive()


def sleep(seconds: float) -> None:
    """``time.sleep(seconds)``, nothing for 0 or less (a deadline already past)."""
    if seconds > 0:
        time.sleep(seconds)
