"""Pydantic description of a capture run: ports, baud rates, tilt schedule, mount geometry.

Only this module imports pydantic; the drivers and capture functions take plain values.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

__all__ = ["LmsSettings", "TiltSettings", "TiltSchedule", "MountGeometry", "CaptureConfig", "load_capture_config"]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class LmsSettings(_Strict):
    """The LMS2xx: its port, baud rates (the device starts at ``initial_baudrate``), the
    scan variant (``fov`` degrees at ``resolution`` hundredths of a degree, ``units``), and
    the timeouts and resends of its protocol."""

    port: str | None = None
    baudrate: Literal[9600, 19200, 38400, 500000] = 38400
    initial_baudrate: Literal[9600, 19200, 38400, 500000] = 9600
    fov: Literal[100, 180] = 180
    resolution: Literal[25, 50, 100] = 100
    units: Literal["mm", "cm"] = "mm"
    timeout: float = Field(3.0, gt=0, description="silence (s) before DeviceTimeout")
    reply_timeout: float = Field(1.0, gt=0)
    gap_timeout: float = Field(0.05, gt=0, description="silence (s) that ends an incomplete telegram")
    probe_timeout: float = Field(0.2, gt=0)
    settle: float = Field(0.25, ge=0)
    config_timeout: float = Field(15.0, gt=0, description="reply timeout of a configuration write (EEPROM)")
    mode_timeout: float = Field(3.0, gt=0, description="reply timeout of a baud-rate change")
    nak_delay: float = Field(0.03, ge=0, description="pause before resending after a NAK (the device needs 30 ms)")
    ack_timeout: float | None = Field(None, gt=0, description="resend a scan request nothing answered "
                                      "(not even the ACK) within this; None: wait reply_timeout")
    attempts: int = Field(30, ge=1, description="sends per command before giving up (a noisy line garbles many)")
    scan_attempts: int = Field(2000, ge=1, description="sends per row before giving up")

    @model_validator(mode="after")
    def _variant_exists(self):
        if self.resolution == 25 and self.fov != 100:
            raise ValueError(f"resolution 25 (0.25 deg) needs fov 100; got fov {self.fov}")
        return self


class TiltSettings(_Strict):
    """The PowerCube tilt unit: its port, module id, baud rate, ramp motion, timeouts and resends."""

    port: str | None = None
    module_id: int = Field(11, ge=1, le=31)
    baudrate: Literal[9600, 19200, 38400] = 9600
    velocity: float = Field(0.5, gt=0, description="ramp velocity, rad/s")
    acceleration: float = Field(1.0, gt=0, description="ramp acceleration, rad/s^2")
    timeout: float = Field(2.0, gt=0)
    reply_timeout: float = Field(0.2, gt=0)
    attempts: int = Field(50, ge=1)
    move_timeout: float = Field(10.0, gt=0)
    poll_interval: float = Field(0.01, ge=0)
    position_tolerance: float = Field(1e-3, gt=0, description="rad; a farther actual angle re-commands the move")


class TiltSchedule(_Strict):
    """The tilt angles of a stop-and-go capture: ``rows`` evenly from ``start`` to ``stop`` (rad)."""

    start: float = -0.4
    stop: float = 0.3
    rows: int = Field(70, ge=1)

    def angles(self) -> np.ndarray:
        """The ``rows`` tilt angles (rad), ``start`` to ``stop`` inclusive."""
        return np.linspace(self.start, self.stop, self.rows)


class MountGeometry(_Strict):
    """The scanner on the tilt unit: ``offset``, the mirror centre from the tilt axis in the
    tilting frame (m), and ``tilt_sign``, which turns the unit's angle into the scan's
    (:class:`rangeseg_o3d.geometry.NoddingGeometry`)."""

    offset: tuple[float, float, float] = (0.0, 0.0, 0.1)
    tilt_sign: Literal[-1, 1] = 1


class CaptureConfig(_Strict):
    """A whole capture. ``mode`` 'stop_and_go' (row by row) or 'continuous' (nodding sweep)."""

    lms: LmsSettings = LmsSettings()
    tilt: TiltSettings = TiltSettings()
    schedule: TiltSchedule = TiltSchedule()
    mount: MountGeometry = MountGeometry()
    mode: Literal["stop_and_go", "continuous"] = "stop_and_go"
    discard_stale: bool = True
    row_retries: int = Field(3, ge=0, description="re-initialisations per row after a reset or silence")
    continuous_velocity: float = Field(0.2, gt=0, description="rad/s during a continuous sweep")
    scan_latency: float | None = Field(None, ge=0, description="s from the middle of a streamed scan's measurement "
                                       "to its last byte's arrival; None: half a mirror revolution plus the transfer time")
    partial_path: Path | None = None


def load_capture_config(source) -> CaptureConfig:
    """A CaptureConfig from a mapping, a YAML path, or an existing CaptureConfig."""
    if isinstance(source, CaptureConfig):
        return source
    if source is None:
        return CaptureConfig()
    if isinstance(source, dict):
        return CaptureConfig.model_validate(source)
    if isinstance(source, (str, Path)):
        import yaml

        data = yaml.safe_load(Path(source).read_text())
        return CaptureConfig.model_validate(data.get("capture", data) if isinstance(data, dict) else data)
    raise TypeError(f"config must be a CaptureConfig, dict or path; got {type(source).__name__}")
