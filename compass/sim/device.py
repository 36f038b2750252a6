"""A simulated compass module: scripted motion through the forward model, streamed on a pty.

The module carries the sensor a calibration describes (its channels' directions and responses,
inverted by :meth:`compass.model.SensorModel.field`), an accelerometer (units of g) and a gyro
(rad/s, with a constant bias) aligned with the housing H, and sends the line protocol of
:mod:`compass.io.lines` (header with checksum, repeated every second; ``t_s`` and ``seq``).

The motion script (:func:`scripted_motion`) repeats every 40 s:

====== ==============================================================
 s      motion
====== ==============================================================
0-4    still, heading 30 deg, level
4-14   slow turn to heading 210 while pitching up to 20 deg and back
14-22  roll +-25 deg
22-32  slow turn to 270; a magnet nearby from 22.5 to 31 s (0.5 s ramps)
32-40  turn back to heading 30 (390), level
====== ==============================================================

Other stream formats (``fmt``: MotionCal's ``Raw:``/``Uni:`` lines, bare numbers) and the
calibration packet a MotionCal board receives are in :mod:`compass.sim.stream_formats`.

The magnet adds ``(0, 0.3, 0.15) |B|`` in the NWU world frame: |B| grows about 8 %, the dip drops
about 9 degrees at a 60-degree site, and an unprotected heading turns by up to 30 degrees.
"""

from __future__ import annotations

import os
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ..frames import r_world_from_housing, world_field
from ..io.lines import format_line
from ..io.motioncal import cal_lines as mc_cal_lines
from ..model import SensorModel
from ..response import LinearResponse
from . import stream_formats
from ._pty import open_pty, write_or_count

__all__ = ["DeviceSamples", "PtyDevice", "default_model", "scripted_motion", "tumble_motion", "simulate_device",
           "MAGNET_PERIOD_S", "MOTIONS"]

PERIOD_S = 40.0
MAGNET_PERIOD_S = (22.5, 31.0)  # magnet fully present between these times (plus 0.5 s ramps outside)
MAGNET_FIELD = np.array([0.0, 0.3, 0.15])  # NWU, in units of |B|
_HEADER_EVERY_S = 1.0


def _ease(t, t0, t1):
    """0 before t0, 1 after t1, a half cosine in between (zero slope at both ends)."""
    u = np.clip((np.asarray(t, dtype=float) - t0) / (t1 - t0), 0.0, 1.0)
    return 0.5 - 0.5 * np.cos(np.pi * u)


def scripted_motion(t_s) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The module's scripted attitude and magnet (see the module docstring).

    Parameters
    ----------
    t_s : array_like, shape (n,)
        Time, seconds (the script repeats every 40 s).

    Returns
    -------
    heading_deg, pitch_deg, roll_deg : ndarray, shape (n,)
        SPEC section 1 angles.
    magnet : ndarray, shape (n,)
        How much of the magnet's field is present, 0..1.
    """
    t = np.mod(np.asarray(t_s, dtype=float), PERIOD_S)
    heading = 30.0 + 180.0 * _ease(t, 4, 14) + 60.0 * _ease(t, 22, 32) + 120.0 * _ease(t, 32, 40)
    pitch = 20.0 * np.sin(np.pi * _ease(t, 4, 14))
    roll = 25.0 * np.sin(2 * np.pi * np.clip((t - 14.0) / 8.0, 0.0, 1.0))
    lo, hi = MAGNET_PERIOD_S
    magnet = _ease(t, lo - 0.5, lo) - _ease(t, hi, hi + 0.5)
    return np.mod(heading, 360.0), pitch, roll, magnet


def tumble_motion(t_s) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A brisk tumble for a free-motion calibration, no magnet.

    Heading turns steadily (90 deg/s), pitch swings +-80 degrees (5.3 s) and roll +-170 degrees
    (3.7 s, so the module is turned over twice a period); the incommensurate periods fill the
    sphere of field directions: 60 % of it in 15 s, 88 % in 30 s (200 cells). Same returns as
    :func:`scripted_motion` (magnet always 0).
    """
    t = np.asarray(t_s, dtype=float)
    heading = np.mod(90.0 * t, 360.0)
    pitch = 80.0 * np.sin(2.0 * np.pi * t / 5.3)
    roll = 170.0 * np.sin(2.0 * np.pi * t / 3.7)
    return heading, pitch, roll, np.zeros(t.shape)


MOTIONS = {"script": scripted_motion, "tumble": tumble_motion}


@dataclass(frozen=True)
class DeviceSamples:
    """What the module measures, and the truth.

    Attributes
    ----------
    t_s : ndarray, shape (n,)
    raw : ndarray, shape (n, c)
        Channel outputs (output units of the calibration).
    accel : ndarray, shape (n, 3)
        Accelerometer in H, g.
    gyro : ndarray, shape (n, 3)
        Gyro in H, rad/s (bias and noise included).
    rotation : Rotation
        True ``R_world<-housing``, n rotations.
    heading_deg, pitch_deg, roll_deg : ndarray, shape (n,)
        True attitude.
    magnet : ndarray, shape (n,)
        Fraction of the magnet's field present.
    """

    t_s: np.ndarray
    raw: np.ndarray
    accel: np.ndarray
    gyro: np.ndarray
    rotation: Rotation
    heading_deg: np.ndarray
    pitch_deg: np.ndarray
    roll_deg: np.ndarray
    magnet: np.ndarray


def default_model() -> SensorModel:
    """The module's sensor when no calibration is given: three linear channels near X, Y, Z.

    |B| = 50 uT, dip 60 degrees, outputs in volts (1.5 V + 20 mV/uT), noise 0.15 uT.
    """
    directions = Rotation.from_rotvec([0.01, -0.02, 0.015]).apply(np.eye(3))
    responses = tuple(LinearResponse(1.5 + 0.01 * c, 0.02 * (1 + 0.05 * c), (-50.0, 50.0)) for c in range(3))
    return SensorModel(("mx", "my", "mz"), directions, responses, 50.0, 50.0, 60.0,
                       noise=np.array([0.15 * r.gain for r in responses]))


def simulate_device(model: SensorModel, t_s, *, motion=scripted_motion, seed: int = 0, accel_noise_g: float = 0.002,
                    gyro_noise: float = 3e-4, gyro_bias=None, rate_hz: float | None = None,
                    imu_from_model=None) -> DeviceSamples:
    """The module's samples at times ``t_s``.

    Parameters
    ----------
    model : SensorModel
        The sensor: channel directions and responses, |B|, dip and channel noise (``noise``).
    t_s : array_like, shape (n,)
        Sample times, seconds.
    motion : callable
        ``motion(t_s) -> (heading_deg, pitch_deg, roll_deg, magnet)`` as :func:`scripted_motion`.
    seed : int
        Seeds the noise (and the gyro bias when ``gyro_bias`` is None).
    accel_noise_g : float
        Accelerometer white noise per axis, g.
    gyro_noise : float
        Gyro rate noise density, rad/s/sqrt(Hz); per-sample sigma ``gyro_noise * sqrt(rate_hz)``.
    gyro_bias : array_like, shape (3,), optional
        Constant gyro bias, rad/s; default drawn with 0.01 rad/s per axis.
    rate_hz : float, optional
        Sample rate for the gyro noise; default from the spacing of ``t_s``.
    imu_from_model : ndarray, shape (3, 3), optional
        The rotation taking the model's frame into the module's accelerometer (and gyro) frame: the
        transpose of :attr:`compass.calibration.ImuCorrection.rotation` of its calibration file (a bench
        ``mag_to_accel``, an installed alignment); default the model's frame.
    """
    t = np.asarray(t_s, dtype=float)
    rng = np.random.default_rng(seed)
    bias = rng.normal(0.0, 0.01, 3) if gyro_bias is None else np.asarray(gyro_bias, dtype=float)
    if rate_hz is None:
        rate_hz = 1.0 / float(np.median(np.diff(t))) if len(t) > 1 else 100.0
    heading, pitch, roll, magnet = motion(t)
    rot = r_world_from_housing(heading, pitch, roll)
    step = 1e-4  # s, central difference of the attitude for the body rate
    before = r_world_from_housing(*motion(t - step / 2)[:3])
    after = r_world_from_housing(*motion(t + step / 2)[:3])
    omega_h = (before.inv() * after).as_rotvec() / step
    field_w = world_field(model.dip_deg, model.field_norm) + np.outer(magnet, MAGNET_FIELD) * model.field_norm
    field_h = rot.apply(field_w, inverse=True)
    x = field_h @ model.unit_directions.T
    noise = np.zeros(len(model.channels)) if model.noise is None else np.asarray(model.noise)
    raw = np.column_stack([r.output(x[:, c]) for c, r in enumerate(model.responses)])
    raw = raw + noise * rng.normal(size=raw.shape)
    n = len(t)
    accel = rot.apply(np.array([0.0, 0.0, 1.0]), inverse=True).reshape(n, 3) + accel_noise_g * rng.normal(size=(n, 3))
    gyro = omega_h.reshape(n, 3) + bias + gyro_noise * np.sqrt(rate_hz) * rng.normal(size=(n, 3))
    if imu_from_model is not None:
        accel, gyro = accel @ np.transpose(imu_from_model), gyro @ np.transpose(imu_from_model)
    return DeviceSamples(t, raw, accel, gyro, rot, heading, pitch, roll, magnet)


@dataclass
class PtyDevice:
    """The simulated module on a pseudo-terminal, streaming in real time.

    Parameters
    ----------
    model : SensorModel
        The module's sensor (see :func:`simulate_device`).
    rate_hz : float
        Samples per second.
    seed : int
    link : path, optional
        Keep a symbolic link here to the current pty (a stable name across disconnects).
    garbage_rate, truncate_rate : float
        Probability per sample of sending a line of random bytes before it / of cutting it short.
    disconnect_at_s, disconnect_for_s : float, optional
        Close the pty at this module time and open a new one after this long (the link is
        absent meanwhile, as a device node is when a USB cable is out).
    gyro : bool
        Send ``gx,gy,gz``.
    motion : callable
        ``motion(t_s) -> (heading_deg, pitch_deg, roll_deg, magnet)``: :func:`scripted_motion`
        (default) or :func:`tumble_motion`.
    imu_from_model : ndarray, shape (3, 3), optional
        The accelerometer's and gyro's frame against the model's (see :func:`simulate_device`).
    fmt : str
        One of :data:`compass.sim.stream_formats.DEVICE_FORMATS`: ``compass`` (the line protocol),
        ``motioncal`` / ``motioncal-raw`` (a MotionCal sketch: its field must be in uT, and it takes
        the calibration packet the host writes, echoing what it stores), ``csv`` (bare numbers).

    Attributes
    ----------
    path : str
        The current pty (slave) path, once :meth:`open` ran.
    counts : dict
        ``samples``, ``garbage``, ``truncated``, ``overflow`` (lines the pty refused because no
        one read them), ``disconnects``, ``packets`` (calibration packets accepted).
    receiver : compass.sim.stream_formats.PacketReceiver
        The MotionCal formats' calibration store.
    """

    model: SensorModel
    rate_hz: float = 100.0
    seed: int = 0
    link: Path | None = None
    garbage_rate: float = 0.0
    truncate_rate: float = 0.0
    disconnect_at_s: float | None = None
    disconnect_for_s: float = 1.0
    gyro: bool = True
    motion: object = scripted_motion
    imu_from_model: object = None
    fmt: str = "compass"
    path: str | None = None
    counts: dict = field(default_factory=lambda: dict.fromkeys(
        ("samples", "garbage", "truncated", "overflow", "disconnects", "packets"), 0))
    receiver: stream_formats.PacketReceiver = field(default_factory=stream_formats.PacketReceiver)
    on_path: object = None
    _fds: tuple = ()
    _echo_in: int = stream_formats.ECHO_EVERY  # samples until the next Cal1:/Cal2: echo

    def __post_init__(self):
        if not self.rate_hz > 0:
            raise ValueError(f"rate must be positive, got {self.rate_hz}")
        for name in ("garbage_rate", "truncate_rate"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {getattr(self, name)}")
        if self.fmt not in stream_formats.DEVICE_FORMATS:
            raise ValueError(f"format must be one of {', '.join(stream_formats.DEVICE_FORMATS)}, got {self.fmt!r}")
        if self.fmt != "compass" and not self.gyro:
            raise ValueError(f"a {self.fmt} stream always carries the gyro")
        if self.fmt.startswith("motioncal") and not abs(stream_formats.outputs_per_ut(self.model) - 1.0) < 0.3:
            raise ValueError("MotionCal lines carry the field in uT: this sensor's outputs are not in uT "
                             f"({stream_formats.outputs_per_ut(self.model):.3g} output units per uT)")
        columns = ["t_s", "seq", *self.model.channels, "ax", "ay", "az"] + (["gx", "gy", "gz"] if self.gyro else [])
        self._header = format_line(columns) if self.fmt == "compass" else b""

    def open(self) -> str:
        """Create the pty (and the link); return its path."""
        master, slave, self.path = open_pty(self.link, blocking=False)
        self._fds = (master, slave)
        if self.on_path is not None:
            self.on_path(self.path)
        return self.path

    def close(self) -> None:
        """Close the pty (the reader sees the device vanish) and remove the link."""
        if self.link is not None:
            Path(self.link).unlink(missing_ok=True)
        for fd in self._fds:
            os.close(fd)
        self._fds = ()

    def run(self, stop: threading.Event, duration_s: float | None = None) -> None:
        """Stream until ``stop`` is set or ``duration_s`` of module time has passed; closes the pty."""
        rng = np.random.default_rng(self.seed + 1)
        if not self._fds:
            self.open()
        start = time.perf_counter()
        block = max(1, int(self.rate_hz * 0.05))
        sent = 0
        next_header = 0.0
        skip_until = 0.0  # module time: samples due while the device was unplugged are never sent
        disconnect_at = self.disconnect_at_s
        try:
            while not stop.is_set():
                t = (sent + np.arange(block)) / self.rate_hz
                if duration_s is not None:
                    t = t[t < duration_s]
                    if not len(t):
                        break
                samples = simulate_device(self.model, t, motion=self.motion, seed=self.seed + sent,
                                          rate_hz=self.rate_hz, imu_from_model=self.imu_from_model,
                                          gyro_bias=np.random.default_rng(self.seed).normal(0.0, 0.01, 3))
                for i, line in enumerate(self._lines(samples, sent)):
                    t_i = t[i]
                    if t_i < skip_until:
                        continue
                    delay = start + t_i - time.perf_counter()
                    if delay > 0:
                        if stop.wait(delay):
                            return
                    if disconnect_at is not None and t_i >= disconnect_at:
                        disconnect_at = None
                        self._disconnect(stop)
                        if stop.is_set():
                            return
                        skip_until = time.perf_counter() - start
                        next_header = skip_until
                        continue
                    if t_i >= next_header and self._header:
                        self._write(self._header)
                        next_header = t_i + _HEADER_EVERY_S
                    if self.garbage_rate and rng.random() < self.garbage_rate:
                        self.counts["garbage"] += 1
                        self._write(_garbage(rng))
                    if self.truncate_rate and rng.random() < self.truncate_rate:
                        self.counts["truncated"] += 1
                        last_cell = max(line.rfind(b","), line.rfind(b" "))  # comma or space separated
                        line = line[: int(rng.integers(1, last_cell))] + b"\r\n"
                    self._write(line)
                    self.counts["samples"] += 1
                    if self.fmt.startswith("motioncal"):
                        self._motioncal_host()
                sent += len(t)
        finally:
            if self._fds:
                self.close()

    def _disconnect(self, stop: threading.Event) -> None:
        self.counts["disconnects"] += 1
        self.close()
        if not stop.wait(self.disconnect_for_s):
            self.open()

    def _write(self, data: bytes) -> None:
        write_or_count(self._fds[0], data, self.counts)

    def _motioncal_host(self) -> None:
        """Take what the host wrote (a calibration packet) and echo the stored calibration now and then."""
        try:
            data = os.read(self._fds[0], 4096)
        except (BlockingIOError, OSError):
            data = b""
        if data and self.receiver.feed(data):
            self.counts["packets"] += 1
            self._write(b"Wrote calibration\r\n")  # what Adafruit's sketch says (a line no decoder reads)
            self._echo_in = 0
        self._echo_in -= 1
        if self._echo_in < 0:
            self._write(mc_cal_lines(self.receiver.stored))
            self._echo_in = stream_formats.ECHO_EVERY

    def _lines(self, s: DeviceSamples, first_seq: int) -> list[bytes]:
        if self.fmt != "compass":
            return stream_formats.sample_lines(self.fmt, s.t_s, s.raw, s.accel, s.gyro)
        rows = np.column_stack([s.raw, s.accel] + ([s.gyro] if self.gyro else []))
        n_raw = s.raw.shape[1]
        fmt = ",".join(["%.7g"] * n_raw + ["%.5f"] * (rows.shape[1] - n_raw))
        return [format_line([f"{t:.4f}", first_seq + i, fmt % tuple(row)])
                for i, (t, row) in enumerate(zip(s.t_s, rows))]


def _garbage(rng: np.random.Generator) -> bytes:
    """A line of 1-16 random bytes: printable or not, never a line end nor a comment's '#'."""
    pool = np.array([b for b in range(0x21, 0x100) if b not in (0x23, 0x7F)], dtype=np.uint8)
    return bytes(rng.choice(pool, int(rng.integers(1, 17)))) + b"\r\n"
