"""Acquisition: SICK LMS2xx and PowerCube drivers, capture procedures, device simulators.

pyserial is imported only when a port is opened by name; importing this package is cheap.
"""

from .capture import PartialCapture, capture, capture_continuous, capture_stop_and_go
from .config import CaptureConfig, load_capture_config
from .errors import (
    AcquisitionError,
    CaptureError,
    DeviceTimeout,
    LmsDeviceReset,
    LmsProtocolError,
    PowerCubeProtocolError,
    ProtocolError,
)
from .lms2xx import crc16, encode_telegram
from .lms_driver import Lms2xx
from .powercube_driver import PowerCube
from .simulate import simulated_capture
from .tilt import TiltUnit

__all__ = [
    "crc16",
    "encode_telegram",
    "Lms2xx",
    "PowerCube",
    "TiltUnit",
    "CaptureConfig",
    "load_capture_config",
    "capture",
    "capture_stop_and_go",
    "capture_continuous",
    "PartialCapture",
    "simulated_capture",
    "AcquisitionError",
    "ProtocolError",
    "LmsProtocolError",
    "LmsDeviceReset",
    "PowerCubeProtocolError",
    "DeviceTimeout",
    "CaptureError",
]
