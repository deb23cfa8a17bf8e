"""Exceptions raised by the acquisition drivers; all derive from :class:`AcquisitionError`."""

from __future__ import annotations

__all__ = [
    "AcquisitionError",
    "ProtocolError",
    "LmsProtocolError",
    "LmsDeviceReset",
    "PowerCubeProtocolError",
    "DeviceTimeout",
    "CaptureError",
]


#: Unanswered requests in a row (besides ``timeout`` of silence) before the device counts as
#: gone: a request garbled on the line is not answered either, and at 3 % byte faults one
#: in five requests is garbled; eight in a row happen about once in 200 000.
SILENT_REQUESTS = 8


class AcquisitionError(Exception):
    """Base of every error the acquisition package raises on purpose.

    ``partial`` carries the rows captured before the failure (a
    :class:`~rangeseg_o3d.acquisition.capture.PartialCapture`) when a capture was running.
    """

    partial = None


class ProtocolError(AcquisitionError):
    """A byte stream or frame that does not follow a device protocol."""


class LmsProtocolError(ProtocolError):
    """Malformed, corrupted or unexpected SICK LMS2xx telegram."""


class LmsDeviceReset(LmsProtocolError):
    """The LMS sent a power-on / reset telegram: its mode, variant and baud rate are back to defaults."""


class PowerCubeProtocolError(ProtocolError):
    """Malformed, corrupted or unexpected PowerCube M5 frame, or a module error state."""


class DeviceTimeout(AcquisitionError):
    """A device stayed silent for longer than the configured timeout.

    Attributes
    ----------
    port : str
        Name of the serial port that stayed silent.
    seconds : float
        How long it stayed silent.
    """

    def __init__(self, port: str, seconds: float, what: str = "device"):
        self.port = str(port)
        self.seconds = float(seconds)
        self.what = what
        super().__init__(
            f"{what} on {self.port} did not answer within {self.seconds:.3g} s "
            "(unplugged, powered off, wrong port or wrong baud rate?)"
        )


class CaptureError(AcquisitionError):
    """A capture could not be completed; ``partial`` holds the rows already captured."""
