"""Capture from the simulated rig over pseudo-terminals: the whole real serial path, no hardware."""

from __future__ import annotations

from .capture import capture
from .config import CaptureConfig, load_capture_config
from .lms2xx import scan_count

__all__ = ["simulated_capture", "simulation_config"]

# Host-side timing for the simulated line: simulated time runs fast, so the host's
# waits for silence can be short; the protocol's 30 ms after a NAK is kept.
_SIM_LMS = {"timeout": 1.0, "reply_timeout": 0.3, "gap_timeout": 0.01, "probe_timeout": 0.1, "settle": 0.005}
_SIM_TILT = {"timeout": 1.0, "reply_timeout": 0.05, "poll_interval": 0.001}


def simulation_config(config=None, *, lms_port: str, tilt_port: str, time_scale: float = 1.0) -> CaptureConfig:
    """``config`` with the simulator's ports, short host-side timeouts and scaled scan latency.

    Timeouts set explicitly in ``config`` are kept.
    """
    config = load_capture_config(config)
    lms_set, tilt_set = config.lms.model_fields_set, config.tilt.model_fields_set
    lms = config.lms.model_copy(update={"port": lms_port, **{k: v for k, v in _SIM_LMS.items() if k not in lms_set}})
    tilt = config.tilt.model_copy(update={"port": tilt_port, **{k: v for k, v in _SIM_TILT.items() if k not in tilt_set}})
    transfer = (2 * scan_count(config.lms.fov, config.lms.resolution) + 10) * 10 / config.lms.baudrate
    latency = config.scan_latency if config.scan_latency is not None else transfer * time_scale
    return config.model_copy(update={"lms": lms, "tilt": tilt, "scan_latency": latency})


def simulated_capture(config=None, faults: float = 0.0, seed: int = 0, *, scene=None, row_ranges=None,
                      time_scale: float = 0.01, noise: float = 0.005, out=None, rig_options: dict | None = None):
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
                       out=out)
