"""Hand-held motion with ground truth, through an IMU with bias, scale error, noise and latency.

What BROAD does by hand, as a forward model: each *kind* of motion is a smooth angular rate and
a smooth position, both sums of sinusoids with random frequencies and phases (so the truth is
analytic: the world-frame acceleration is the position's second derivative), optionally cut by
rests, plus impulses (tapping) or a fast sinusoid (vibration):

================  =====================================  ============================================
 kind              rotation (rms rate per axis)           translation
================  =====================================  ============================================
 slow_rotation     30 deg/s, 0.1-0.5 Hz                   none
 fast_rotation     150 deg/s, 0.3-1.5 Hz                  none
 slow_translation  5 deg/s                                 0.15 m, 0.2-0.6 Hz (about 1 m/s^2)
 fast_translation  10 deg/s                                0.10 m, 0.8-2.0 Hz (about 6 m/s^2)
 breaks            slow_rotation, still 4 s every 12 s    none
 tapping           5 deg/s                                 2 ms impulses of 5 g, 2 per second
 vibration         5 deg/s                                 25 Hz, 3 m/s^2 (and 1 deg/s of it in rate)
================  =====================================  ============================================

The attitude is the exact integral of the angular rate (``R_k = R_k-1 Exp(omega_k dt)``, NWU world,
FLU housing, SPEC section 1); the field is homogeneous (|B|, dip) unless the module walks between
rooms (``places``: from a moment on the world field is another |B|, dip and declination, reached
over ``Place.transition_s``, the walk through a door; the truth stays in the first place's frame, so
a heading that follows the new field's North is off by its declination) or a magnet is fixed to
the housing (``housing_field``: a constant field in H from a moment on); the specific force is
``R^T (a + g z)``.  The sensors: gyro ``(I + S) omega + b + n``, accelerometer ``(I + S_a) f + b_a + n``
(m/s^2), magnetometer the field ``latency_s`` late plus noise.  Nothing here is fitted to BROAD; the
filter never sees what was injected (tests compare its output with :attr:`MotionRecording.rotation`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ..frames import world_field

__all__ = ["KINDS", "SensorErrors", "Place", "HousingField", "MotionRecording", "simulate_motion", "read_sensors",
           "moving_rows"]

GRAVITY = 9.81
KINDS = ("slow_rotation", "fast_rotation", "slow_translation", "fast_translation", "breaks", "tapping", "vibration")
_ROTATION = {"slow_rotation": (30.0, 0.1, 0.5), "fast_rotation": (150.0, 0.3, 1.5), "breaks": (30.0, 0.1, 0.5),
             "slow_translation": (5.0, 0.1, 0.5), "fast_translation": (10.0, 0.1, 0.5), "tapping": (5.0, 0.1, 0.5),
             "vibration": (5.0, 0.1, 0.5)}  # rms rate per axis (deg/s), frequency band (Hz)
_TRANSLATION = {"slow_translation": (0.15, 0.2, 0.6), "fast_translation": (0.10, 0.8, 2.0)}  # amplitude m, band Hz
_TONES = 5  # sinusoids per axis


@dataclass(frozen=True)
class SensorErrors:
    """What the simulated IMU gets wrong (all in the housing frame H).

    Attributes
    ----------
    gyro_bias_rad_s : tuple of 3 floats
    gyro_scale : tuple of 3 floats
        Relative scale error of each gyro axis (0.01 = 1 %).
    gyro_noise : float
        Rate noise density, rad/s/sqrt(Hz).
    accel_bias_m_s2 : tuple of 3 floats
    accel_scale : tuple of 3 floats
        Relative scale error of each accelerometer axis (0.02 = 2 %).
    accel_noise_m_s2 : float
        Per-sample white noise of each axis, m/s^2.
    mag_noise_ut : float
        Per-sample white noise of each axis, uT.
    mag_latency_s : float
        The magnetometer reads the field this late, s.
    mag_rate_hz : float
        The magnetometer's own conversion rate, Hz: each reading is held on the rows until its next conversion, as
        a stream faster than a magnetometer sends it (0: a new reading every row).
    """

    gyro_bias_rad_s: tuple = (0.0, 0.0, 0.0)
    gyro_scale: tuple = (0.0, 0.0, 0.0)
    gyro_noise: float = 1e-4
    accel_bias_m_s2: tuple = (0.0, 0.0, 0.0)
    accel_scale: tuple = (0.0, 0.0, 0.0)
    accel_noise_m_s2: float = 0.05
    mag_noise_ut: float = 0.7
    mag_latency_s: float = 0.0
    mag_rate_hz: float = 0.0


@dataclass(frozen=True)
class Place:
    """The field of a room the module walks into.

    Attributes
    ----------
    t_s : float
        When the walk into it starts, s.
    field_ut, dip_deg : float
        Its |B| and dip.
    declination_deg : float
        How far its horizontal field is turned from the first place's North (east positive), degrees.
    transition_s : float
        How long the field takes to change (the walk through the door), s.
    """

    t_s: float
    field_ut: float
    dip_deg: float
    declination_deg: float = 0.0
    transition_s: float = 2.0

    def world(self) -> np.ndarray:
        """The place's field in the first place's NWU frame, uT, shape (3,)."""
        return Rotation.from_euler("z", -self.declination_deg, degrees=True).apply(world_field(self.dip_deg, self.field_ut))


@dataclass(frozen=True)
class HousingField:
    """A magnet (or magnetised part) fixed to the housing from a moment on, until another.

    Attributes
    ----------
    t_s : float
        When it is put on, s.
    field_ut : tuple of 3 floats
        The constant field it adds in H, uT.
    until_s : float
        When it is taken off, s (default: never).
    """

    t_s: float
    field_ut: tuple
    until_s: float = math.inf


@dataclass(frozen=True)
class MotionRecording:
    """A simulated trial: the truth and the sensors' readings.

    Attributes
    ----------
    kind : str
    t_s : ndarray, shape (n,)
    rotation : Rotation, n rotations
        True ``R_world<-housing`` (NWU world).
    rate_rad_s : ndarray, shape (n, 3)
        True angular rate in H over ``(t_k-1, t_k]``, rad/s.
    specific_force_m_s2 : ndarray, shape (n, 3)
        True specific force in H, m/s^2.
    moving : ndarray of bool, shape (n,)
        Rate above 1 deg/s or motion acceleration above 0.05 m/s^2.
    gyro_rad_s, accel_m_s2, mag_ut : ndarray, shape (n, 3)
        The sensors' readings.
    field_ut, dip_deg : float
        The first place's field.
    errors : SensorErrors
    places : tuple of Place
    housing_field : HousingField or None
    """

    kind: str
    t_s: np.ndarray
    rotation: Rotation
    rate_rad_s: np.ndarray
    specific_force_m_s2: np.ndarray
    moving: np.ndarray
    gyro_rad_s: np.ndarray
    accel_m_s2: np.ndarray
    mag_ut: np.ndarray
    field_ut: float
    dip_deg: float
    errors: SensorErrors
    places: tuple = ()
    housing_field: HousingField | None = None


def _tones(rng, t, rms, f_lo, f_hi, axes=3):
    """Sum of ``_TONES`` sinusoids per axis with frequencies in [f_lo, f_hi] Hz, total rms ``rms``;
    returns the signal and its second derivative."""
    f = rng.uniform(f_lo, f_hi, (axes, _TONES))
    phase = rng.uniform(0.0, 2.0 * np.pi, (axes, _TONES))
    amp = rms * np.sqrt(2.0 / _TONES)
    arg = 2.0 * np.pi * f[None] * t[:, None, None] + phase[None]
    w2 = (2.0 * np.pi * f[None]) ** 2
    return amp * np.sin(arg).sum(axis=2), -amp * (w2 * np.sin(arg)).sum(axis=2)


def simulate_motion(kind: str, *, duration_s: float = 60.0, rate_hz: float = 285.714, seed: int = 0,
                    errors: SensorErrors = SensorErrors(), field_ut: float = 43.0, dip_deg: float = 69.0,
                    rest_s: float = 3.0, places=(), housing_field: HousingField | None = None) -> MotionRecording:
    """Simulate one trial of ``kind`` (:data:`KINDS`), still for ``rest_s`` at both ends.

    Parameters
    ----------
    kind : str
    duration_s, rate_hz : float
    seed : int
        Seeds the motion and the noise.
    errors : SensorErrors
    field_ut, dip_deg : float
        The homogeneous field (a Berlin-like default).
    rest_s : float
        Still time at the start and at the end, s.
    places : sequence of Place
        Rooms walked into, in time order (the first place's field is ``field_ut``, ``dip_deg``).
    housing_field : HousingField, optional
        A magnet put on the housing.

    Returns
    -------
    MotionRecording
    """
    if kind not in KINDS:
        raise ValueError(f"expected kind in {KINDS}, got {kind!r}")
    rng = np.random.default_rng(seed)
    n = int(round(duration_s * rate_hz))
    t = np.arange(n) / rate_hz
    dt = 1.0 / rate_hz
    # the envelope: 0 at rest, 1 moving, 1 s ramps (smooth: the rate and acceleration stay continuous)
    ramp = np.clip(np.minimum(t - rest_s, duration_s - rest_s - t), 0.0, 1.0)
    envelope = 0.5 - 0.5 * np.cos(np.pi * ramp)
    if kind == "breaks":
        phase = np.mod(t - rest_s, 12.0)
        envelope = envelope * (0.5 - 0.5 * np.cos(np.pi * np.clip(np.minimum(phase, 8.0 - phase), 0.0, 1.0)))
    rms_deg, f_lo, f_hi = _ROTATION[kind]
    rate = np.radians(_tones(rng, t, rms_deg, f_lo, f_hi)[0]) * envelope[:, None]
    accel_world = np.zeros((n, 3))
    if kind in _TRANSLATION:
        amp, f_lo, f_hi = _TRANSLATION[kind]
        # position = envelope * tones: its exact second derivative, envelope's ramps included
        p, p2 = _tones(rng, t, amp, f_lo, f_hi)
        e1 = np.gradient(envelope, dt)
        e2 = np.gradient(e1, dt)
        p1 = np.gradient(p, dt, axis=0)
        accel_world = e2[:, None] * p + 2.0 * e1[:, None] * p1 + envelope[:, None] * p2
    elif kind == "tapping":
        taps = np.flatnonzero((rng.random(n) < 2.0 * dt) & (envelope > 0.99))
        for k in taps:
            direction = rng.normal(size=3)
            accel_world[k:k + max(1, int(round(0.002 * rate_hz)))] += 5.0 * GRAVITY * direction / np.linalg.norm(direction)
    elif kind == "vibration":
        accel_world = 3.0 * np.sqrt(2.0) * np.sin(2.0 * np.pi * 25.0 * t)[:, None] * rng.normal(size=3) / np.sqrt(3.0)
        accel_world *= envelope[:, None]
        rate = rate + np.radians(np.sqrt(2.0)) * np.sin(2.0 * np.pi * 25.0 * t + 1.0)[:, None] \
            * envelope[:, None] * rng.normal(size=3) / np.sqrt(3.0)
    # attitude: the exact integral of the piecewise-constant rate from a random start
    steps = Rotation.from_rotvec(rate * dt)
    start = Rotation.from_euler("ZYX", [rng.uniform(0, 360), rng.uniform(-20, 20), rng.uniform(-20, 20)], degrees=True)
    quats = np.empty((n, 4))
    r = start
    quats[0] = r.as_quat()
    for k in range(1, n):  # sample k's rate turns the housing over (t_k-1, t_k], as a gyro's reading does
        r = r * steps[k]
        quats[k] = r.as_quat()
    rotation = Rotation.from_quat(quats)
    specific = rotation.apply(accel_world + [0.0, 0.0, GRAVITY], inverse=True)
    field_w = np.tile(world_field(dip_deg, field_ut), (n, 1))
    for place in places:  # a raised-cosine walk from the field there to the place's
        share = 0.5 - 0.5 * np.cos(np.pi * np.clip((t - place.t_s) / place.transition_s, 0.0, 1.0))
        field_w = field_w + share[:, None] * (place.world() - field_w)
    field_h = rotation.apply(field_w, inverse=True)
    if housing_field is not None:
        on = (t >= housing_field.t_s) & (t < housing_field.until_s)
        field_h = field_h + np.where(on[:, None], np.asarray(housing_field.field_ut, float), 0.0)
    gyro, accel, mag = read_sensors(rng, t, rate_hz, rate, specific, field_h, errors)
    return MotionRecording(kind, t, rotation, rate, specific, moving_rows(rate, accel_world), gyro, accel, mag,
                           field_ut, dip_deg, errors, tuple(places), housing_field)


def read_sensors(rng, t, rate_hz: float, rate, specific, field_h, errors: SensorErrors):
    """The IMU's readings of a true motion: gyro ``(I + S) omega + b + n``, accelerometer ``(I + S_a) f + b_a + n``,
    magnetometer the field ``latency_s`` late plus noise (noise drawn from ``rng`` in that order), each reading held
    until the next conversion when ``errors.mag_rate_hz`` is set.

    Parameters
    ----------
    rng : numpy.random.Generator
    t : ndarray, shape (n,)
        Sample times, s.
    rate_hz : float
        The sample rate (the gyro's noise density to per-sample noise), Hz.
    rate : ndarray, shape (n, 3)
        True angular rate in H, rad/s.
    specific : ndarray, shape (n, 3)
        True specific force in H, m/s^2.
    field_h : ndarray, shape (n, 3)
        True field in H, uT.
    errors : SensorErrors

    Returns
    -------
    gyro_rad_s, accel_m_s2, mag_ut : ndarray, shape (n, 3)
    """
    e, n = errors, len(t)
    gyro = rate * (1.0 + np.asarray(e.gyro_scale)) + e.gyro_bias_rad_s \
        + e.gyro_noise * np.sqrt(rate_hz) * rng.normal(size=(n, 3))
    accel = specific * (1.0 + np.asarray(e.accel_scale)) + e.accel_bias_m_s2 \
        + e.accel_noise_m_s2 * rng.normal(size=(n, 3))
    if e.mag_latency_s > 0.0:
        field_h = np.column_stack([np.interp(t - e.mag_latency_s, t, field_h[:, i]) for i in range(3)])
    mag = field_h + e.mag_noise_ut * rng.normal(size=(n, 3))
    if e.mag_rate_hz > 0.0:  # a conversion at the first row of each period, held until the next
        period = np.floor((t - t[0]) * e.mag_rate_hz + 1e-9)
        converted = np.r_[True, period[1:] != period[:-1]]
        mag = mag[np.maximum.accumulate(np.where(converted, np.arange(n), 0))]
    return gyro, accel, mag


def moving_rows(rate, accel_world) -> np.ndarray:
    """:attr:`MotionRecording.moving`: rate (rad/s, shape (n, 3)) above 1 deg/s or motion acceleration (m/s^2,
    shape (n, 3)) above 0.05 m/s^2, shape (n,)."""
    return (np.linalg.norm(rate, axis=1) > np.radians(1.0)) | (np.linalg.norm(accel_world, axis=1) > 0.05)
