"""Capture a nodding-laser scan: stop-and-go row by row, or a continuous sweep.

A failed capture raises :class:`~rangeseg_o3d.acquisition.errors.AcquisitionError`
(usually :class:`DeviceTimeout`) whose ``partial`` attribute is a :class:`PartialCapture`
with every row completed so far; with ``config.partial_path`` set it is also saved
there (atomically) as an OrganizedCloud ``.npz``.
"""

from __future__ import annotations

import logging
import sys
import time
from dataclasses import dataclass, field

import numpy as np

from ..cloud import OrganizedCloud
from .errors import AcquisitionError, DeviceTimeout, LmsDeviceReset, LmsProtocolError, PowerCubeProtocolError
from .lms2xx import beam_angles

__all__ = ["PartialCapture", "CaptureProgress", "capture_stop_and_go", "capture_continuous", "capture",
           "open_devices", "initialise", "retries"]

log = logging.getLogger(__name__)


@dataclass
class PartialCapture:
    """Rows captured so far (each row: ranges (W,), actual tilt, timestamp)."""

    beam_angles: np.ndarray
    mount_offset: tuple
    tilt_sign: float
    ranges: list = field(default_factory=list)
    tilts: list = field(default_factory=list)
    timestamps: list = field(default_factory=list)

    @property
    def n_rows(self) -> int:
        return len(self.ranges)

    def add(self, ranges, tilt: float, timestamp: float) -> None:
        self.ranges.append(np.asarray(ranges, dtype=float))
        self.tilts.append(float(tilt))
        self.timestamps.append(float(timestamp))

    def to_cloud(self) -> OrganizedCloud | None:
        """The rows so far as an OrganizedCloud, or None if there are none."""
        if not self.ranges:
            return None
        return OrganizedCloud.from_ranges(
            np.vstack(self.ranges), self.beam_angles, np.asarray(self.tilts),
            mount_offset=self.mount_offset, tilt_sign=self.tilt_sign, timestamps=np.asarray(self.timestamps),
        )


def _new_partial(config) -> PartialCapture:
    return PartialCapture(beam_angles(config.lms.fov, config.lms.resolution), tuple(config.mount.offset),
                          float(config.mount.tilt_sign))


def initialise(lms, tilt, config, *, tilt_too: bool = True) -> None:
    """Bring both devices into capture state (LMS: rate, mode, variant, units; tilt: home, ramp)."""
    s = config.lms
    lms.initialise(baudrate=s.baudrate, fov=s.fov, resolution=s.resolution, units=s.units)
    if tilt_too:
        t = config.tilt
        tilt.initialise(velocity=t.velocity, acceleration=t.acceleration, timeout=t.move_timeout)


def _move(tilt, target: float, config) -> float:
    """Move, wait for the end of the move, read the actual angle; re-command a move that went astray."""
    t = config.tilt
    actual = None
    for _ in range(t.attempts):
        tilt.move_to(target)
        tilt.wait_until_stopped(t.move_timeout)
        actual = tilt.position()
        if abs(actual - target) <= t.position_tolerance:
            return actual
        log.debug("tilt at %.5f instead of %.5f; moving again", actual, target)
    raise PowerCubeProtocolError(f"tilt unit on {tilt.port} does not reach {target:.4f} rad (at {actual})")


def _read_row(lms, config) -> np.ndarray:
    if config.discard_stale:
        try:  # a scan that may predate the end of the move: one try, result thrown away
            lms.request_scan(attempts=1)
        except (LmsProtocolError, DeviceTimeout) as err:
            if isinstance(err, LmsDeviceReset):
                raise
    return lms.request_scan(attempts=config.lms.scan_attempts).ranges


def _keep_partial(partial: PartialCapture, config) -> bool:
    """Save the rows so far to ``config.partial_path`` (atomically); True if saved."""
    if config.partial_path is None or not partial.n_rows:
        return False
    try:
        partial.to_cloud().save(config.partial_path)
    except Exception as save_err:  # the capture's own error matters more than a failed save
        log.error("could not save the partial capture to %s: %s", config.partial_path, save_err)
        return False
    log.warning("saved %d captured rows to %s", partial.n_rows, config.partial_path)
    return True


def _fail(err: BaseException, partial: PartialCapture, config) -> BaseException:
    """``err`` with ``.partial`` attached, after saving the rows so far (Ctrl-C included)."""
    try:
        err.partial = partial
    except AttributeError:  # an exception type without a __dict__
        pass
    _keep_partial(partial, config)
    return err


def retries(lms, tilt) -> int:
    """Requests the drivers have had to resend so far (NAK, corrupted, broken or unanswered)."""
    counted = ("nak", "bad_frames", "broken", "silent")
    return sum(getattr(device, "stats", {}).get(key, 0) for device in (lms, tilt) for key in counted)


class CaptureProgress:
    """``row 12/70, 3 retries, 4.2 s elapsed, ETA 20 s`` rewritten in place on a terminal.

    Quiet when ``stream`` is not a terminal (a log file or a pipe gets nothing), unless
    ``always`` is set. Call it with ``(rows_done, retries)``; :meth:`close` ends the line.
    """

    def __init__(self, total: int, stream=None, *, always: bool = False):
        self.total = int(total)
        self.stream = sys.stderr if stream is None else stream
        isatty = getattr(self.stream, "isatty", None)
        self.enabled = always or bool(callable(isatty) and isatty())
        self.start = time.monotonic()
        self._shown = False

    def line(self, done: int, resent: int) -> str:
        elapsed = time.monotonic() - self.start
        eta = f"ETA {elapsed / done * (self.total - done):.0f} s" if done else "ETA ?"
        return f"row {done}/{self.total}, {resent} retries, {elapsed:.1f} s elapsed, {eta}"

    def __call__(self, done: int, resent: int) -> None:
        if self.enabled:
            self.stream.write("\r" + self.line(done, resent) + "  ")
            self.stream.flush()
            self._shown = True

    def close(self) -> None:
        if self._shown:
            self.stream.write("\n")
            self.stream.flush()
            self._shown = False


def capture_stop_and_go(lms, tilt, config, *, on_row=None, progress=None) -> OrganizedCloud:
    """Row by row: move, wait, read back the angle, discard a stale scan, request one scan.

    After a power-on telegram or silence the LMS is re-initialised and the row re-read
    (up to ``config.row_retries`` times per row).

    Parameters
    ----------
    lms : Lms2xx
    tilt : TiltUnit
    config : CaptureConfig
    on_row : callable, optional
        ``on_row(index, ranges, tilt)`` after each row.
    progress : callable, optional
        ``progress(rows_done, retries)`` after each row (e.g. a :class:`CaptureProgress`).

    Raises
    ------
    AcquisitionError
        With ``.partial`` holding the rows captured so far. Any other exception, Ctrl-C
        (KeyboardInterrupt) included, also saves the rows so far to ``config.partial_path``.
    """
    partial = _new_partial(config)
    try:
        for k, target in enumerate(config.schedule.angles()):
            actual, ranges = _capture_row(lms, tilt, config, k, float(target), partial)
            partial.add(ranges, actual, time.time())
            if on_row is not None:
                on_row(k, ranges, actual)
            if progress is not None:
                progress(partial.n_rows, retries(lms, tilt))
    except AcquisitionError:
        raise  # _capture_row attached and saved the partial capture
    except BaseException as err:  # Ctrl-C, a vanished port: keep what was captured
        raise _fail(err, partial, config)
    return partial.to_cloud()


def _capture_row(lms, tilt, config, k: int, target: float, partial: PartialCapture):
    """Move to ``target`` and read one row; after a reset or silence re-initialise the LMS and retry."""
    for retry in range(config.row_retries + 1):
        try:
            return _move(tilt, target, config), _read_row(lms, config)
        except (LmsDeviceReset, DeviceTimeout) as err:
            if isinstance(err, DeviceTimeout) and err.port != lms.port or retry == config.row_retries:
                raise _fail(err, partial, config) from None
            log.warning("row %d: %s; re-initialising the LMS", k, err)
            try:
                initialise(lms, tilt, config, tilt_too=False)
            except AcquisitionError as again:
                raise _fail(again, partial, config) from err
        except AcquisitionError as err:
            raise _fail(err, partial, config) from None
    raise AssertionError("unreachable: the last retry raises")


def capture_continuous(lms, tilt, config) -> OrganizedCloud:
    """One sweep from ``schedule.start`` to ``schedule.stop`` with the LMS streaming.

    The tilt position is polled during the sweep; each scan's tilt is interpolated at
    its timestamp (arrival time minus the transfer time at the line rate). Scans lost
    to line errors are simply missing rows.
    """
    s = config.schedule
    partial = _new_partial(config)
    try:
        _move(tilt, s.start, config)
        tilt.set_ramp(config.continuous_velocity, config.tilt.acceleration)
        lms.start_streaming()
        latency = config.scan_latency
        if latency is None:  # the scan was measured about one transfer time before it arrived
            latency = (2 * partial.beam_angles.size + 10) * 10 / config.lms.baudrate
        samples = [(time.monotonic(), tilt.position(confirmations=1))]
        scans = []
        tilt.move_to(s.stop)
        deadline = time.monotonic() + abs(s.stop - s.start) / config.continuous_velocity * 3 + config.tilt.move_timeout
        while time.monotonic() < deadline:
            got = lms.read_streamed(config.tilt.poll_interval or 0.01)
            if got is not None:
                scans.append((got[1] - latency, got[0].ranges))
            moving = tilt.state() & 0x800
            samples.append((time.monotonic(), tilt.read_position()))
            if not moving:
                break
        lms.stop_streaming()
        tilt.set_ramp(config.tilt.velocity, config.tilt.acceleration)
    except AcquisitionError as err:
        raise _fail(err, partial, config) from None
    t, pos = np.array(samples).T
    wall = time.time() - time.monotonic()
    for stamp, ranges in scans:
        if t[0] <= stamp <= t[-1]:
            partial.add(ranges, float(np.interp(stamp, t, pos)), stamp + wall)
    if not partial.n_rows:
        raise CaptureEmpty("the continuous sweep produced no scans")
    return partial.to_cloud()


class CaptureEmpty(AcquisitionError):
    """A capture finished without a single row."""


def open_devices(config):
    """Drivers for the ports in ``config`` (``lms.port`` and ``tilt.port`` must be set)."""
    from .lms_driver import Lms2xx
    from .powercube_driver import PowerCube

    if not config.lms.port or not config.tilt.port:
        raise ValueError(f"lms.port and tilt.port must be set; got {config.lms.port!r}, {config.tilt.port!r}")
    s, t = config.lms, config.tilt
    lms = Lms2xx(s.port, initial_baudrate=s.initial_baudrate, timeout=s.timeout, reply_timeout=s.reply_timeout,
                 gap_timeout=s.gap_timeout, attempts=s.attempts, settle=s.settle, probe_timeout=s.probe_timeout,
                 nak_delay=s.nak_delay, ack_timeout=s.ack_timeout, config_timeout=s.config_timeout,
                 mode_timeout=s.mode_timeout)
    try:
        tilt = PowerCube(t.port, module_id=t.module_id, baudrate=t.baudrate, timeout=t.timeout,
                         reply_timeout=t.reply_timeout, attempts=t.attempts, poll_interval=t.poll_interval)
    except Exception:
        lms.close()
        raise
    return lms, tilt


def capture(config, *, out=None, progress=None) -> OrganizedCloud:
    """Open the devices named in ``config``, initialise them, capture, optionally save to ``out``.

    ``out`` is written atomically through :meth:`OrganizedCloud.save`; if that fails, the
    capture is saved to ``config.partial_path`` instead (when set) before the error is raised.
    ``progress(rows_done, retries)`` is called after each row of a stop-and-go capture.
    """
    lms, tilt = open_devices(config)
    try:
        try:
            initialise(lms, tilt, config)
        except AcquisitionError as err:
            raise _fail(err, _new_partial(config), config) from None
        if config.mode == "continuous":
            cloud = capture_continuous(lms, tilt, config)
        else:
            cloud = capture_stop_and_go(lms, tilt, config, progress=progress)
    finally:
        lms.close()
        tilt.close()
    if out is not None:
        try:
            cloud.save(out)
        except Exception as err:
            whole = PartialCapture(cloud.geometry.beam_angles, tuple(config.mount.offset),
                                   float(config.mount.tilt_sign))
            for row, tilt_angle, stamp in zip(cloud.ranges, cloud.geometry.tilt_angles, cloud.timestamps):
                whole.add(row, tilt_angle, stamp)
            raise _fail(err, whole, config)
    return cloud
