"""A transport that debug-logs every byte written to and read from a device.

:func:`rangeseg_o3d.acquisition.transport.open_transport` wraps every port in a
:class:`LoggedTransport`, so each serial exchange of the drivers appears on the logger
``rangeseg_o3d.acquisition.logged_transport`` at DEBUG level as hex, for example::

    DEBUG rangeseg_o3d.acquisition.logged_transport /dev/ttyUSB0 > 02 00 01 00 31 15 12
    DEBUG rangeseg_o3d.acquisition.logged_transport /dev/ttyUSB0 < 06 02 80 ...

Library logging is quiet by default (no handler is installed); turn it on with
``logging.basicConfig(level=logging.DEBUG)`` or by configuring that logger.
"""

from __future__ import annotations

import logging

__all__ = ["LoggedTransport", "port_name"]

log = logging.getLogger(__name__)


def port_name(transport) -> str:
    """A human-readable name for error messages."""
    name = getattr(transport, "port", None) or getattr(transport, "name", None)
    return str(name) if name else type(transport).__name__


class LoggedTransport:
    """Wrap a serial-like transport: ``write`` and ``read`` are logged, everything else passes through.

    Attribute reads and writes (``baudrate``, ``timeout``, ``in_waiting``, ``fileno``,
    ``reset_input_buffer``, a fake's own fields, ...) reach the wrapped object, so a
    driver cannot tell the difference. ``name`` labels the log lines (the port name).
    """

    __slots__ = ("_inner", "_name")

    def __init__(self, inner, name: str | None = None):
        if isinstance(inner, LoggedTransport):
            inner = inner.inner
        object.__setattr__(self, "_inner", inner)
        if name is None:
            name = port_name(inner)
        object.__setattr__(self, "_name", str(name))

    @property
    def inner(self):
        """The wrapped transport."""
        return self._inner

    def write(self, data):
        """Write ``data`` to the wrapped transport, logging it first (a write that fails is logged too)."""
        if log.isEnabledFor(logging.DEBUG):
            log.debug("%s > %s", self._name, bytes(data).hex(" "))
        return self._inner.write(data)

    def read(self, size: int = 1) -> bytes:
        """Read from the wrapped transport; what arrived is logged (silence is not)."""
        data = self._inner.read(size)
        if data and log.isEnabledFor(logging.DEBUG):
            log.debug("%s < %s", self._name, bytes(data).hex(" "))
        return data

    def __getattr__(self, name):
        # only reached for names not defined here: the wrapped transport's attributes
        return getattr(self._inner, name)

    def __setattr__(self, name, value):
        setattr(self._inner, name, value)

    def __repr__(self) -> str:
        return f"LoggedTransport({self._inner!r})"
