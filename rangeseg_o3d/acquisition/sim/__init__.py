"""Virtual LMS200 and PowerCube devices served over pseudo-terminals, with injectable faults."""

from .clock import SimClock
from .faults import LineFaults
from .lms200 import VirtualLms200
from .powercube import VirtualPowerCube
from .pty import Output, PtyDevice
from .rig import SimulatedRig

__all__ = ["SimClock", "LineFaults", "VirtualLms200", "VirtualPowerCube", "Output", "PtyDevice", "SimulatedRig"]
