"""The tilt-unit interface the capture code depends on; a PowerCube implements it."""

from __future__ import annotations

import time
from abc import ABC, abstractmethod

__all__ = ["TiltUnit"]


class TiltUnit(ABC):
    """A one-axis tilt unit. Angles in radians in the unit's own sign convention."""

    port: str = "?"

    @abstractmethod
    def initialise(self, *, velocity: float, acceleration: float, timeout: float) -> None:
        """Clear errors, home, and set the motion ramp."""

    @abstractmethod
    def move_to(self, angle: float) -> None:
        """Start a move to ``angle``; returns at once."""

    @abstractmethod
    def wait_until_stopped(self, timeout: float) -> None:
        """Block until the last move has ended; DeviceTimeout / protocol error otherwise."""

    @abstractmethod
    def position(self) -> float:
        """The actual angle, read back from the unit."""

    def timed_position(self) -> tuple[float, float]:
        """(host ``time.monotonic()``, actual angle) while the unit may be moving.

        This default dates :meth:`position` by the middle of the call; a driver that knows
        when the unit read its angle says so instead.
        """
        before = time.monotonic()
        angle = self.position()
        return 0.5 * (before + time.monotonic()), angle

    @abstractmethod
    def halt(self) -> None:
        """Stop any motion."""

    def close(self) -> None:
        """Release the port."""
