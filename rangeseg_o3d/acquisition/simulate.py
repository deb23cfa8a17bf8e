"""Capture from the simulated rig over pseudo-terminals: the whole real serial path, no hardware."""

from __future__ import annotations

from .capture import capture
from .config import CaptureConfig, load_capture_config
from .lms2xx import scan_count, stream_latency

__all__ = ["simulated_capture", "simulation_config"]

# The host's waits on a simulated line are the hardware's (the settings' defaults) times the
# time scale, as the devices' own timing is; each has a floor in wall seconds, because the
# operating system's scheduling does not speed up with the simulation (a few ms on a busy
# machine) and a dead device must still be told from a slow host.
_LMS_FLOORS = {"timeout": 0.5, "reply_timeout": 0.02, "gap_timeout": 0.002, "probe_timeout": 0.02,
               "settle": 0.0, "nak_delay": 0.0, "config_timeout": 0.1, "mode_timeout": 0.05}
# The simulated LMS acknowledges a request within one byte time, as the real one does at
# once: a request nothing answered within 60 ms of device time was lost on the line.
_SIM_ACK = 0.06
_ACK_FLOOR = 0.015
_SIM_POSITION_TOLERANCE = 1e-6  # rad
_TILT_FLOORS = {"timeout": 0.5, "reply_timeout": 0.02, "poll_interval": 0.0, "move_timeout": 2.0}


def _scaled_waits(settings, floors: dict, time_scale: float) -> dict:
    """The waits of ``settings`` not set explicitly, scaled to the simulation's time."""
    defaults = type(settings).model_fields
    return {name: max(defaults[name].default * time_scale, floor) for name, floor in floors.items()
            if name not in settings.model_fields_set}


def simulation_config(config=None, *, lms_port: str, tilt_port: str, time_scale: float = 1.0) -> CaptureConfig:
    """``config`` with the simulator's ports, host waits scaled by ``time_scale`` and scaled scan latency.

    Waits set explicitly in ``config`` are kept.
    """
    config = load_capture_config(config)
    lms_waits = _scaled_waits(config.lms, _LMS_FLOORS, time_scale)
    if "ack_timeout" not in config.lms.model_fields_set:
        lms_waits["ack_timeout"] = max(_SIM_ACK * time_scale, _ACK_FLOOR)
    lms = config.lms.model_copy(update={"port": lms_port, **lms_waits})
    tilt_settings = _scaled_waits(config.tilt, _TILT_FLOORS, time_scale)
    if "position_tolerance" not in config.tilt.model_fields_set:
        # The simulated unit stops exactly at its target (as float32): a stop 0.1 mrad away
        # means a move command corrupted past the 8-bit BCC, to be sent again.
        tilt_settings["position_tolerance"] = _SIM_POSITION_TOLERANCE
    tilt = config.tilt.model_copy(update={"port": tilt_port, **tilt_settings})
    device_latency = stream_latency(scan_count(config.lms.fov, config.lms.resolution), config.lms.baudrate)
    latency = config.scan_latency if config.scan_latency is not None else device_latency * time_scale
    return config.model_copy(update={"lms": lms, "tilt": tilt, "scan_latency": latency})


def simulated_capture(config=None, faults: float = 0.0, seed: int = 0, *, scene=None, row_ranges=None,
                      time_scale: float = 0.01, noise: float = 0.005, out=None, rig_options: dict | None = None,
                      progress=None):
    """Capture a scan from a virtual LMS200 on a virtual PowerCube.

    Parameters
    ----------
    config : CaptureConfig, dict, path or None
        Capture settings (ports are replaced by the simulators' ptys); default CaptureConfig().
    faults : float
        Probability that a byte on either line is corrupted or dropped.
    seed : int
        Seeds the line faults and the range noise.
    scene : rangeseg_o3d.synthetic.Scene, optional
        Default ``rangeseg_o3d.synthetic.suite.default_scene()``.
    row_ranges : callable, optional
        Replaces the scene (tests): ``row_ranges(tilt, beam_angles) -> ranges``.
    time_scale : float
        Wall seconds per simulated second.
    noise : float
        Range noise sigma (m), reproducible per tilt angle.
    out : path, optional
        Save the cloud there (atomically).
    rig_options : dict, optional
        Extra :class:`~rangeseg_o3d.acquisition.sim.rig.SimulatedRig` arguments (fault events).
    progress : callable, optional
        ``progress(rows_done, retries)`` after each row (see :class:`~.capture.CaptureProgress`).

    Returns
    -------
    OrganizedCloud
        With NoddingGeometry (actual tilt angles), ranges and per-row timestamps.
    """
    from .sim.rig import SimulatedRig

    config = load_capture_config(config)
    rig = SimulatedRig(scene, row_ranges=row_ranges, time_scale=time_scale, faults=faults, seed=seed,
                       mount_offset=config.mount.offset, tilt_sign=config.mount.tilt_sign, noise=noise,
                       **(rig_options or {}))
    with rig:
        return capture(simulation_config(config, lms_port=rig.lms_port, tilt_port=rig.tilt_port, time_scale=time_scale),
                       out=out, progress=progress)
