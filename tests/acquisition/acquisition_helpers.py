"""Shared test helpers: a flat wall standing in for a synthetic scene, the simulated rig's devices opened,
a call that must raise rather than hang."""

import threading
from contextlib import contextmanager

import numpy as np
import pytest

from rangeseg_o3d.acquisition.capture import initialise, open_devices
from rangeseg_o3d.acquisition.lms2xx import SCAN_PERIOD
from rangeseg_o3d.acquisition.simulate import simulation_config
from rangeseg_o3d.acquisition.powercube import ramp_profile
from rangeseg_o3d.geometry import NoddingGeometry, nodding_rays

WALL_X = 3.0
MOUNT = (0.0, 0.0, 0.1)


def wall_ranges(tilt, beams, *, mount=MOUNT, tilt_sign=1.0, wall_x=WALL_X):
    """Exact ranges to the plane x = wall_x (inf where a beam misses it)."""
    o, d = nodding_rays(NoddingGeometry(beams, np.array([tilt]), mount, tilt_sign))
    o, d = o[0], d[0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (wall_x - o[:, 0]) / d[:, 0]
    return np.where(np.isfinite(t) & (t > 0), t, np.inf)


def scans_in_sweep(start, stop, velocity, acceleration=1.0, baudrate=38400, margin=1e-3):
    """Scans an LMS streams (181 values) while a trapezoidal move from ``start`` to ``stop`` is
    more than ``margin`` rad from both: the time it spends there over the stream's beat, one
    scan per mirror revolution or per transfer when the line is slower."""
    duration = ramp_profile(abs(stop - start), velocity, acceleration, 0.0)[1]
    at_ends = 2 * np.sqrt(2 * margin / acceleration)  # time to leave the start and to reach the stop by margin
    beat = max(SCAN_PERIOD, (2 * 181 + 10) * 10 / baudrate)
    return (duration - at_ends) / beat


@contextmanager
def rig_devices(rig, config, time_scale):
    """``(simulation config, lms, tilt)`` of a started SimulatedRig, initialised; both closed on leaving."""
    sim = simulation_config(config, lms_port=rig.lms_port, tilt_port=rig.tilt_port, time_scale=time_scale)
    lms, tilt = open_devices(sim)
    try:
        initialise(lms, tilt, sim)
        yield sim, lms, tilt
    finally:
        lms.close()
        tilt.close()


def raises_without_hanging(exception, call, match=None, seconds=5.0):
    """What ``call()`` raises, run in a thread; fails if it does not raise ``exception`` or still runs
    after ``seconds`` (a hang: the thread is left behind as a daemon)."""
    raised = []

    def run():
        with pytest.raises(exception, match=match) as info:
            call()
        raised.append(info.value)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join(seconds)
    assert not thread.is_alive(), f"{call} still running after {seconds} s"
    assert raised, f"{call} did not raise {exception.__name__}"
    return raised[0]
