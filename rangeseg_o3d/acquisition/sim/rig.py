"""A simulated nodding rig: a virtual LMS200 on a virtual PowerCube, each on its own pty."""

from __future__ import annotations

from .clock import SimClock
from .faults import LineFaults
from .lms200 import VirtualLms200
from .powercube import VirtualPowerCube
from .pty import PtyDevice

__all__ = ["SimulatedRig"]


class SimulatedRig:
    """Start both simulators in threads; use as a context manager.

    Parameters
    ----------
    scene : rangeseg_o3d.synthetic.Scene, optional
        What the laser sees; default ``rangeseg_o3d.synthetic.suite.default_scene()``.
    row_ranges : callable, optional
        Replaces ``scene``: ``row_ranges(tilt, beam_angles) -> ranges``.
    time_scale : float
        Wall seconds per simulated second (0.01: a 1 s move takes 10 ms).
    faults : float
        Probability that any byte on either line is corrupted or dropped.
    seed : int
    mount_offset, tilt_sign, noise
        The true mounting and range noise (metres).
    lms_options : dict
        Extra VirtualLms200 arguments (``nak_rate``, ``reset_after_scans``, ``silent``).
    tilt_options : dict
        Extra VirtualPowerCube arguments (``silent``, ``start_position``).

    Attributes
    ----------
    lms_port, tilt_port : str
        Slave pty paths to open with pyserial.
    """

    def __init__(self, scene=None, *, row_ranges=None, time_scale: float = 0.01, faults: float = 0.0,
                 seed: int = 0, mount_offset=(0.0, 0.0, 0.1), tilt_sign: float = 1.0, noise: float = 0.0,
                 lms_options: dict | None = None, tilt_options: dict | None = None):
        if scene is None and row_ranges is None:
            from ...synthetic.suite import default_scene

            scene = default_scene()
        self.clock = SimClock(time_scale)
        self.cube = VirtualPowerCube(self.clock, **(tilt_options or {}))
        self.lms = VirtualLms200(self.clock, scene, row_ranges=row_ranges, tilt_at=self.cube.position_at,
                                 mount_offset=mount_offset, tilt_sign=tilt_sign, noise=noise, seed=seed,
                                 **(lms_options or {}))
        self.lms_link = PtyDevice(self.lms, LineFaults(faults, seed))
        self.tilt_link = PtyDevice(self.cube, LineFaults(faults, seed + 1))
        self.lms_port = self.lms_link.port
        self.tilt_port = self.tilt_link.port

    def start(self) -> "SimulatedRig":
        self.lms_link.start()
        self.tilt_link.start()
        return self

    def stop(self) -> None:
        try:
            self.lms_link.stop()
        finally:
            self.tilt_link.stop()

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()
