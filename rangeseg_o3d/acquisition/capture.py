"""Capture a nodding-laser scan: stop-and-go row by row, or a continuous sweep.

A failed capture raises :class:`~rangeseg_o3d.acquisition.errors.AcquisitionError`
(usually :class:`DeviceTimeout`) whose ``partial`` attribute is a :class:`PartialCapture`
with every row completed so far; with ``config.partial_path`` set it is also saved
there (atomically) as an OrganizedCloud ``.npz``. Any failure, Ctrl-C included, first
halts the tilt unit, so it does not go on to the end of its move.
"""

from __future__ import annotations

import logging
import sys
import time
from dataclasses import dataclass, field

import numpy as np

from ..cloud import OrganizedCloud
from .errors import AcquisitionError, DeviceTimeout, LmsDeviceReset, LmsProtocolError, PowerCubeProtocolError
from .lms2xx import beam_angles, stream_latency
from .powercube import STATE, ramp_profile, ramp_time
from .transport import sleep

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


def _fail(err: BaseException, partial: PartialCapture, config, tilt=None, collect=None) -> BaseException:
    """``err`` with ``.partial`` attached, after halting ``tilt`` (when given), adding the rows
    ``collect()`` gathers (when given: a sweep's last streamed scans) and saving the rows so far.

    The halt comes first: a unit left moving goes on to the end of its move while the rows
    are gathered and the file is written. They are gathered and saved even if a second
    Ctrl-C cuts the halt short.
    """
    try:
        err.partial = partial
    except AttributeError:  # an exception type without a __dict__
        pass
    try:
        if tilt is not None:
            _halt(tilt)
    finally:
        try:
            if collect is not None:
                collect()
        finally:
            _keep_partial(partial, config)
    return err


def _halt(tilt) -> None:
    """Stop the tilt unit after a failed capture; a failure to do so is only logged (the capture's own error matters more)."""
    try:
        tilt.halt()
    except Exception as halt_err:
        log.error("could not halt the tilt unit on %s: %s", getattr(tilt, "port", "?"), halt_err)


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
        Either way the tilt unit is halted first (it may be in the middle of a move).
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
        raise  # _capture_row halted the tilt unit, attached and saved the partial capture
    except BaseException as err:  # Ctrl-C, a vanished port: stop the unit, keep what was captured
        raise _fail(err, partial, config, tilt)
    return partial.to_cloud()


def _capture_row(lms, tilt, config, k: int, target: float, partial: PartialCapture):
    """Move to ``target`` and read one row; after a reset or silence re-initialise the LMS and retry."""
    for retry in range(config.row_retries + 1):
        try:
            return _move(tilt, target, config), _read_row(lms, config)
        except (LmsDeviceReset, DeviceTimeout) as err:
            if isinstance(err, DeviceTimeout) and err.port != lms.port or retry == config.row_retries:
                raise _fail(err, partial, config, tilt) from None
            log.warning("row %d: %s; re-initialising the LMS", k, err)
            try:
                initialise(lms, tilt, config, tilt_too=False)
            except AcquisitionError as again:
                raise _fail(again, partial, config, tilt) from err
        except AcquisitionError as err:
            raise _fail(err, partial, config, tilt) from None
    raise AssertionError("unreachable: the last retry raises")


def capture_continuous(lms, tilt, config) -> OrganizedCloud:
    """One sweep from ``schedule.start`` to ``schedule.stop`` with the LMS streaming.

    Every scan the LMS streamed is a row, however slow the host: the driver reads the port
    in a thread and dates each scan by the arrival of its last byte, minus
    ``config.scan_latency`` (default: half a mirror revolution plus the transfer time at
    the line rate). The tilt is sampled all along, each sample dated by when its request
    went out, from a reading at rest before the stream starts to one at rest after it
    stops, and each scan's tilt is interpolated at its date. Every scan whose telegram
    passes its CRC (and the count and unit checks) is a row; scans damaged on the line are
    missing rows, counted in the driver's ``stats["damaged_scans"]`` and logged. A streamed
    scan cannot be rebuilt from repeats as a stop-and-go one can (each is measured at another
    tilt): on a line with byte faults of 1 % few 372-byte scans arrive whole, so
    :class:`CaptureEmpty` says how many were damaged. A failure (Ctrl-C included) keeps the rows whose tilt the samples
    so far bracket and halts the tilt unit in the middle of its sweep, then saves the rows
    like :func:`capture_stop_and_go`; after that the LMS is asked to stop streaming.
    """
    partial = _new_partial(config)
    latency = config.scan_latency
    if latency is None:
        latency = stream_latency(partial.beam_angles.size, config.lms.baudrate)
    scans, samples, ramp = [], [], []
    damaged_before = _damaged_scans(lms)
    try:
        _sweep(lms, tilt, config, scans, samples, ramp)
    except BaseException as err:  # Ctrl-C, a vanished port: stop the unit, keep what was captured
        def last_rows():
            _salvage(lms, scans)
            _add_streamed_rows(partial, scans, samples, ramp, latency)

        try:
            failure = _fail(err, partial, config, tilt, collect=last_rows)
        finally:
            # after the rows are saved, as a dead laser port may take its timeouts; a scan arriving
            # now is after the last tilt sample, so no row could be dated from it anyway (also when
            # a second Ctrl-C cuts the halt short, or the save fails)
            _end_stream(lms)
        raise failure
    _add_streamed_rows(partial, scans, samples, ramp, latency)
    damaged = _damaged_scans(lms) - damaged_before
    if damaged:
        log.warning("%d streamed scans were damaged on the line (CRC) and are missing rows; %d rows kept",
                    damaged, partial.n_rows)
    if not partial.n_rows:
        raise CaptureEmpty(f"the continuous sweep produced no scans ({damaged} damaged on the line; "
                           "on a noisy line capture stop_and_go, which rebuilds a scan from its repeats)")
    return partial.to_cloud()


def _damaged_scans(lms) -> int:
    """Streamed scans the LMS driver has left out as damaged so far (0 for a driver that does not count them)."""
    return getattr(lms, "stats", {}).get("damaged_scans", 0)


def _sweep(lms, tilt, config, scans: list, samples: list, ramp: list) -> None:
    """Stream during the move, appending ``(scan, arrival)`` to ``scans`` and ``(time, tilt)`` to
    ``samples``; ``ramp`` gets the move's start, target, velocity and acceleration."""
    s = config.schedule
    start = _move(tilt, s.start, config)
    tilt.set_ramp(config.continuous_velocity, config.tilt.acceleration)
    ramp.extend((start, s.stop, config.continuous_velocity, config.tilt.acceleration))
    samples.append(tilt.timed_position())
    lms.start_streaming()
    samples.append((time.monotonic(), start))  # still at rest: the move has not been asked for
    tilt.move_to(s.stop)
    deadline = time.monotonic() + abs(s.stop - s.start) / config.continuous_velocity * 3 + config.tilt.move_timeout
    while time.monotonic() < deadline:
        sleep(config.tilt.poll_interval)
        scans.extend(lms.drain_streamed())
        moving = tilt.state() & STATE["motion"]
        samples.append(tilt.timed_position())
        if not moving:
            break
    lms.stop_streaming()
    scans.extend(lms.drain_streamed())
    samples.append(tilt.timed_position())  # after the last scan arrived
    tilt.set_ramp(config.tilt.velocity, config.tilt.acceleration)


def _end_stream(lms) -> None:
    """Take a laser still streaming after a failed sweep back to send-on-request mode, so it does
    not go on filling the line until the next initialise (a failure to do so is only logged)."""
    if not getattr(lms, "streaming", False):
        return
    try:
        lms.stop_streaming()
    except Exception as stop_err:  # the sweep's own error matters more
        log.error("could not stop the LMS stream on %s: %s", getattr(lms, "port", "?"), stop_err)


def _salvage(lms, scans: list) -> None:
    """Add the scans the driver still holds after a failed sweep (a second failure is only logged)."""
    try:
        scans.extend(lms.drain_streamed())
    except Exception as again:  # the sweep's own error matters more
        log.error("could not take the last streamed scans: %s", again)


def _add_streamed_rows(partial: PartialCapture, scans: list, samples: list, ramp: list, latency: float) -> None:
    """Rows for the scans whose date the tilt samples bracket, in arrival order, at the tilt of that date."""
    if not scans or len(samples) < 2 or not ramp:
        return
    t = np.array([when for when, _ in samples])
    stamps = np.array([arrival for _, arrival in scans]) - latency
    inside = (stamps >= t[0]) & (stamps <= t[-1])
    if not inside.all():
        log.warning("%d of %d streamed scans fall outside the tilt samples and are left out",
                    int((~inside).sum()), len(scans))
    tilts = _tilts_at(stamps, samples, *ramp)
    wall = time.time() - time.monotonic()
    for (scan, _), stamp, angle, keep in zip(scans, stamps, tilts, inside):
        if keep:
            partial.add(scan.ranges, float(angle), float(stamp) + wall)


def _tilts_at(stamps: np.ndarray, samples: list, start: float, target: float, velocity: float,
              acceleration: float) -> np.ndarray:
    """The tilt at host times ``stamps``, from the ``(time, tilt)`` samples of a trapezoidal move.

    A slow host polls seldom, and a straight line between samples far apart cuts across the
    ramp's bends. So the ramp itself is fitted to the samples taken in motion (the time each
    one's angle is reached on the ramp, against its host time: a line gives the move's start
    and its pace in host seconds), and only the samples' departures from it are interpolated
    linearly: the samples keep the last word where the unit moved otherwise. A sample the
    line misses by far more than the others (dated late: the host lost its core between the
    request and reading the clock) is left out of both. With fewer than two samples in
    motion, the samples alone are interpolated.
    """
    t, pos = np.array(samples, dtype=float).T
    origin = t[0]  # host times are large: fit and evaluate from the first sample
    t, stamps = t - origin, stamps - origin
    distance, sign = abs(target - start), np.sign(target - start)
    covered = sign * (pos - start)
    moving = (covered > _AT_REST) & (covered < distance - _AT_REST)
    if np.count_nonzero(moving) < 2:
        return np.interp(stamps, t, pos)
    fitted = _fit_ramp_clock(t[moving], ramp_time(distance, velocity, acceleration, covered[moving]))
    if fitted is None:
        return np.interp(stamps, t, pos)
    pace, offset, inliers = fitted
    kept = ~moving
    kept[np.flatnonzero(moving)[inliers]] = True

    def on_ramp(times):
        return start + sign * ramp_profile(distance, velocity, acceleration, pace * times + offset)[0]

    return on_ramp(stamps) + np.interp(stamps, t[kept], pos[kept] - on_ramp(t[kept]))


def _fit_ramp_clock(host: np.ndarray, ramp: np.ndarray):
    """(pace, offset, inliers) of ``ramp ~ pace * host + offset``, refitted without the points it
    misses by more than three robust sigmas and ``_RAMP_SLACK``; None if it does not run forward."""
    inliers = np.ones(host.size, dtype=bool)
    for _ in range(3):
        pace, offset = np.polyfit(host[inliers], ramp[inliers], 1)
        miss = np.abs(ramp - (pace * host + offset))
        again = miss <= max(3 * 1.4826 * np.median(miss[inliers]), _RAMP_SLACK)
        if np.count_nonzero(again) < 2 or np.array_equal(again, inliers):
            break
        inliers = again
    return (pace, offset, inliers) if pace > 0 else None


_AT_REST = 1e-5  # rad: a sample this close to the start or the target may be at rest
_RAMP_SLACK = 0.002  # s of the ramp's time (1 mrad at 0.5 rad/s): a sample this near the line is kept


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
