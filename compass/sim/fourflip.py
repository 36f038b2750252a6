"""The virtual bench: simulated four-flip sessions written as SPEC recordings.

An accelerometer riding in the housing (``ax, ay, az``, :class:`SimAccelerometer`: misaligned with
the housing, with offsets, scale errors and noise) and a turntable whose axis is tilted from the
vertical (it moves gravity and the field as the turntable sees them) are optional and off by
default; they draw from their own random stream, so a session without them is unchanged.

Each effect of SPEC section 4 can be switched on; the simulator's own form of an effect is
deliberately *not* the estimator's (saturation by tanh rather than an odd cubic, warm-up by an
exponential rather than a polynomial, encoder error with a phase) so that tests do not reward a
model tuned to its own simulator.  ``field_gradient`` is an effect the estimators do not model
(a field gradient across the turntable with the sensor off its axis), for honesty tests.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ..frames import bench_rotation, field_in_bench
from ..io.fourflip import FourFlipRecording
from ._files import csv_text, write_with_truth
from .bench import BenchPhysics, BenchSamples, channel_outputs, housing_field

__all__ = ["SIM_EFFECTS", "SimAccelerometer", "SimulatedSession", "simulate_fourflip", "write_fourflip"]

SIM_EFFECTS = (
    "nonlinear_response",
    "encoder_error",
    "offset_drift",
    "platform_field",
    "flip_error",
    "turntable_zero",
    "temperature",
    "field_gradient",
    "gain_drift",
)


@dataclass(frozen=True)
class SimAccelerometer:
    """An accelerometer riding in the housing, read in g: ``a = (1 + s) * (C f_H) + b + noise``.

    Attributes
    ----------
    misalign_deg : float
        RMS of each component of the rotation vector of ``C = R_accel<-H``, degrees.
    noise_g : float
        White noise per axis and sample, g.
    offset_g : float
        RMS of each axis offset ``b``, g.
    scale_error : float
        RMS of each axis' relative scale error ``s``.
    """

    misalign_deg: float = 1.0
    noise_g: float = 0.002
    offset_g: float = 0.0
    scale_error: float = 0.0


@dataclass(frozen=True)
class SimulatedSession:
    """A simulated recording and the truth behind it.

    Attributes
    ----------
    samples : BenchSamples
    outputs : ndarray, shape (n, c)
    channels : tuple of str
    metadata : dict
    truth : dict
        JSON-ready truth (directions, offsets, gains per field unit, dip, effects with parameters).
    accel : ndarray, shape (n, 3), or None
        The accelerometer's readings (g), when the session has one.
    """

    samples: BenchSamples
    outputs: np.ndarray
    channels: tuple[str, ...]
    metadata: dict
    truth: dict
    accel: np.ndarray | None = None

    def recording(self) -> FourFlipRecording:
        """The in-memory recording a CSV of this session reads back as."""
        s = self.samples
        return FourFlipRecording(s.flip_deg, s.flip_index, s.platform_deg, self.outputs, self.channels,
                                 s.t_s, s.temp_c, self.accel, dict(self.metadata))

    def base_physics(self) -> BenchPhysics:
        """The truth's base-model parameters (effects left out), gains per microtesla."""
        t = self.truth
        return BenchPhysics(np.asarray(t["directions"]), np.asarray(t["offsets"]), np.asarray(t["gains_per_ut"]),
                            float(t["dip_deg"]), float(t["azimuth_deg"]), float(t["field_ut"]))

    def outputs_at(self, field_h, temp_c: float | None = None) -> np.ndarray:
        """Noise-free outputs of the simulated sensor for fields in H, at a sensor temperature.

        The base model plus the session's ``temperature`` effect (other effects belong to the
        bench); ``field_h`` in uT, shape (n, 3); ``temp_c`` None reads at the effect's reference.
        """
        field_h = np.asarray(field_h, dtype=float)
        physics = self.base_physics()
        for effect in self.truth["effects"]:
            if effect["name"] == "temperature":
                p = effect["parameters"]
                physics = physics.with_(temp_offset=np.asarray(p["offset_per_degc"]),
                                        temp_gain=np.asarray(p["gain_per_degc"]), temp_ref_c=p["ref_c"])
        zero = np.zeros(len(field_h))
        samples = BenchSamples(zero, zero, zero.astype(int), None,
                               None if temp_c is None else np.full(len(field_h), float(temp_c)))
        return channel_outputs(physics, samples, field_h @ physics.directions.T)


def _nominal_directions(n_channels: int, rng: np.random.Generator, misalign_deg: float) -> np.ndarray:
    """Near X, Y, Z (repeating) for three or fewer channels, random for more; perturbed."""
    base = np.eye(3)[np.arange(n_channels) % 3] if n_channels <= 3 else rng.normal(size=(n_channels, 3))
    base /= np.linalg.norm(base, axis=1, keepdims=True)
    tilt = Rotation.from_rotvec(rng.normal(scale=np.radians(misalign_deg) / np.sqrt(2), size=(n_channels, 3)))
    return tilt.apply(base)


def simulate_fourflip(
    *,
    seed: int = 0,
    n_channels: int = 3,
    effects: tuple[str, ...] = (),
    noise_ut: float = 0.15,
    field_ut: float = 50.0,
    dip_deg: float | None = None,
    step_deg: float = 1.0,
    sample_period_s: float = 0.5,
    misalign_deg: float = 3.0,
    effect_scale: float = 1.0,
    directions: np.ndarray | None = None,
    accelerometer: SimAccelerometer | None = None,
    turntable_tilt_deg: float = 0.0,
) -> SimulatedSession:
    """Simulate one four-flip bench session.

    Parameters
    ----------
    seed : int
        Seeds every random draw (geometry, sensor, effect sizes, noise).
    n_channels : int
        Number of single-axis channels.
    effects : tuple of str
        Names from :data:`SIM_EFFECTS`.
    noise_ut : float
        White noise per sample, microtesla equivalent.
    field_ut, dip_deg : float
        |B| and dip; dip drawn in [40, 70] deg when None; field azimuth is random.
    step_deg, sample_period_s : float
        Turntable step and time per sample; each flip starts at a random turntable angle.
    misalign_deg : float
        RMS misalignment of the channels from the housing axes.
    effect_scale : float
        Multiplies every effect size (1 gives sizes that move a direction by roughly 0.1-1 deg).
    directions : ndarray, shape (c, 3), optional
        Sensing directions to use instead of random ones.
    accelerometer : SimAccelerometer, optional
        Record ``ax, ay, az`` from this accelerometer (none by default).
    turntable_tilt_deg : float
        The turntable's axis tilted from the vertical by this angle, toward a random azimuth: the
        field is seen against the tilted axis (its dip as the turntable sees it changes) and gravity
        in H moves with the turntable angle.  The truth's ``dip_deg`` stays the dip against gravity.
    """
    unknown = set(effects) - set(SIM_EFFECTS)
    if unknown:
        raise ValueError(f"unknown effect(s) {sorted(unknown)}; known: {', '.join(SIM_EFFECTS)}")
    rng = np.random.default_rng(seed)
    if directions is None:
        directions = _nominal_directions(n_channels, rng, misalign_deg)
    directions = np.asarray(directions, float)
    directions = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    n_channels = len(directions)
    gains_per_ut = rng.uniform(0.018, 0.022, n_channels)  # volts per uT
    offsets = 2.5 + rng.normal(scale=0.05, size=n_channels)  # volts
    dip = float(rng.uniform(40.0, 70.0)) if dip_deg is None else float(dip_deg)
    azimuth = float(rng.uniform(0.0, 360.0))

    n_per_flip = int(round(360.0 / step_deg))
    platform, flip, flip_index, t_s = [], [], [], []
    t0 = 0.0
    for k, kappa in enumerate((0.0, 90.0, 180.0, 270.0)):
        start = rng.uniform(0.0, 360.0)
        platform.append(start + step_deg * np.arange(n_per_flip))
        flip.append(np.full(n_per_flip, kappa))
        flip_index.append(np.full(n_per_flip, k))
        t_s.append(t0 + sample_period_s * np.arange(n_per_flip))
        t0 = t_s[-1][-1] + 45.0  # time to flip the cube
    samples = BenchSamples(
        np.mod(np.concatenate(platform), 360.0),
        np.concatenate(flip),
        np.concatenate(flip_index),
        np.concatenate(t_s),
    )
    physics = BenchPhysics(directions, offsets, gains_per_ut, dip, azimuth, field_ut)
    truth_effects = []
    s = effect_scale
    t = samples.t_s

    if "encoder_error" in effects:
        amp = s * np.array([rng.uniform(0.8, 1.6), rng.uniform(0.3, 0.6)])
        phase = rng.uniform(0.0, 2 * np.pi, 2)
        fourier = np.column_stack([amp * np.cos(phase), -amp * np.sin(phase)])
        physics = physics.with_(encoder_fourier=fourier)
        truth_effects.append({"name": "encoder_error", "parameters": {"fourier_deg": fourier.tolist()}})
    if "flip_error" in effects:
        # faces not square: the flip angles err (the X edge stays on the turntable's X axis)
        errors = np.zeros((4, 3))
        errors[1:, 0] = s * rng.choice([-1, 1], 3) * rng.uniform(0.3, 0.7, 3)
        physics = physics.with_(flip_rotvec_deg=errors)
        truth_effects.append({"name": "flip_error", "parameters": {"flip_rotvec_deg": errors.tolist()}})
    if "turntable_zero" in effects:
        # the cube set down turned about the vertical after a flip (no fence, or re-zeroed table): its yaw on the table
        yaw = np.zeros((4, 3))
        yaw[1:, 2] = s * rng.choice([-1, 1], 3) * rng.uniform(0.3, 1.0, 3)
        rotvec = yaw if physics.flip_rotvec_deg is None else physics.flip_rotvec_deg + yaw
        physics = physics.with_(flip_rotvec_deg=rotvec)
        truth_effects.append({"name": "turntable_zero", "parameters": {"yaw_deg": yaw[:, 2].tolist()}})
    if "platform_field" in effects:
        b_p = s * rng.choice([-1, 1], 3) * rng.uniform(0.3, 0.6, 3)
        physics = physics.with_(platform_field=b_p)
        truth_effects.append({"name": "platform_field", "parameters": {"field_ut": b_p.tolist()}})

    temp_c = None
    if "temperature" in effects:
        temp_c = 22.0 + 8.0 * (1 - np.exp(-t / 300.0)) + 2.0 * np.sin(2 * np.pi * t / 230.0)
        temp_offset = s * gains_per_ut * rng.choice([-1, 1], n_channels) * rng.uniform(0.04, 0.08, n_channels)
        temp_gain = s * rng.choice([-1, 1], n_channels) * rng.uniform(1e-3, 2e-3, n_channels)
        physics = physics.with_(temp_offset=temp_offset, temp_gain=temp_gain, temp_ref_c=22.0)
        truth_effects.append(
            {"name": "temperature", "parameters": {"offset_per_degc": temp_offset.tolist(),
                                                   "gain_per_degc": temp_gain.tolist(), "ref_c": 22.0}}
        )
    samples = BenchSamples(samples.platform_deg, samples.flip_deg, samples.flip_index, t, temp_c)

    extra = np.random.default_rng([seed, 0xACC])  # the accelerometer's and the tilt's own stream
    up_turntable, tilted = np.array([0.0, 0.0, 1.0]), physics
    if turntable_tilt_deg:
        lean = float(extra.uniform(0.0, 360.0))
        tau, beta = np.radians(turntable_tilt_deg), np.radians(lean)
        up_turntable = np.array([np.sin(tau) * np.cos(beta), np.sin(tau) * np.sin(beta), np.cos(tau)])
        tilted = physics.with_(**_dip_azimuth(_to_turntable(up_turntable).apply(
            field_in_bench(dip, azimuth, field_ut))))
        truth_effects.append({"name": "turntable_tilt", "parameters": {
            "tilt_deg": float(turntable_tilt_deg), "up_lean_azimuth_deg": lean,
            "up_in_turntable_frame": up_turntable.tolist(), "dip_against_axis_deg": tilted.dip_deg,
            "modelled_by_estimators": False}})
    b_h = housing_field(tilted, samples)
    if "field_gradient" in effects:
        b_h = b_h + _gradient_field(samples, rng, s)
        truth_effects.append({"name": "field_gradient", "parameters": {"modelled_by_estimators": False}})
    x = b_h @ directions.T
    if "nonlinear_response" in effects:
        saturation_ut = rng.uniform(75.0, 100.0, n_channels) / s
        x = saturation_ut * np.tanh(x / saturation_ut)
        truth_effects.append({"name": "nonlinear_response", "parameters": {"tanh_saturation_ut": saturation_ut.tolist()}})
    outputs = channel_outputs(physics.with_(cubic=None), samples, x)
    if "offset_drift" in effects:
        amp = s * gains_per_ut * rng.choice([-1, 1], n_channels) * rng.uniform(0.4, 0.8, n_channels)
        tau = rng.uniform(200.0, 400.0)
        outputs = outputs + amp[None, :] * np.exp(-t / tau)[:, None]
        truth_effects.append({"name": "offset_drift", "parameters": {"amplitude": amp.tolist(), "tau_s": tau}})
    if "gain_drift" in effects:  # the gains change linearly over the session (a room warming up)
        rate = s * rng.choice([-1, 1], n_channels) * rng.uniform(0.003, 0.006, n_channels)
        tau = (t - t.mean()) / (0.5 * np.ptp(t))
        signal = outputs - channel_outputs(physics.with_(cubic=None), samples, np.zeros_like(x))
        outputs = outputs + signal * rate[None, :] * tau[:, None]
        truth_effects.append({"name": "gain_drift", "parameters": {"relative_change_per_half_session": rate.tolist()}})

    noise = noise_ut * gains_per_ut
    outputs = outputs + rng.normal(size=outputs.shape) * noise[None, :]
    accel = None
    if accelerometer is not None:
        accel, truth_accel = _accelerometer(accelerometer, physics, samples, up_turntable, extra)
        truth_effects.append(truth_accel)
    channels = tuple(f"v{i + 1}" for i in range(n_channels))
    truth = {
        "directions": directions.tolist(),
        "offsets": offsets.tolist(),
        "gains_per_ut": gains_per_ut.tolist(),
        "dip_deg": dip,
        "azimuth_deg": azimuth,
        "field_ut": field_ut,
        "noise": noise.tolist(),
        "noise_ut": noise_ut,
        "channels": list(channels),
        "effects": truth_effects,
        "seed": seed,
    }
    metadata = {"field_ut": f"{field_ut:g}", "source": f"compass simulate fourflip --seed {seed}"}
    return SimulatedSession(samples, outputs, channels, metadata, truth, accel)


def _to_turntable(up_turntable) -> Rotation:
    """The rotation taking bench (gravity) vectors into the tilted turntable's frame: true up goes to ``up_turntable``."""
    rotation, _ = Rotation.align_vectors([up_turntable], [[0.0, 0.0, 1.0]])
    return rotation


def _dip_azimuth(vector) -> dict:
    """``dip_deg`` and ``azimuth_deg`` of a field vector (SPEC section 1's form)."""
    v = np.asarray(vector, float)
    return {"dip_deg": float(np.degrees(np.arcsin(-v[2] / np.linalg.norm(v)))),
            "azimuth_deg": float(np.degrees(np.arctan2(v[1], v[0])))}


def _accelerometer(spec: SimAccelerometer, physics, samples, up_turntable, rng) -> tuple[np.ndarray, dict]:
    """Readings (g) of a misaligned accelerometer in H and their truth entry.

    Gravity in H goes through the same forward model as the field (encoder and flip errors included):
    specific force +1 g along true up, written as a "field" of unit magnitude pointing up.
    """
    up = physics.with_(**_dip_azimuth(up_turntable), field_norm=1.0, platform_field=None)
    f_h = housing_field(up, samples)
    rotvec_deg = rng.normal(scale=spec.misalign_deg, size=3)
    offset = rng.normal(scale=spec.offset_g, size=3)
    scale = 1.0 + rng.normal(scale=spec.scale_error, size=3)
    rotation = Rotation.from_rotvec(rotvec_deg, degrees=True)
    accel = scale * rotation.apply(f_h) + offset + rng.normal(scale=spec.noise_g, size=f_h.shape)
    truth = {"name": "accelerometer", "parameters": {
        "mag_to_accel": rotation.as_matrix().tolist(), "rotvec_deg": rotvec_deg.tolist(), "offset_g": offset.tolist(),
        "scale": scale.tolist(), "noise_g": spec.noise_g, "modelled_by_estimators": False}}
    return accel, truth


def _gradient_field(samples, rng, scale) -> np.ndarray:
    """Field of a constant gradient, sampled at a sensor 5 cm off the turntable axis, in H."""
    g = rng.normal(size=(3, 3))
    g = g + g.T
    g -= np.trace(g) / 3 * np.eye(3)  # curl- and divergence-free
    g *= scale * 40.0 / np.linalg.norm(g)  # uT per metre
    offset_h = np.array([0.05, 0.02, 0.0])  # metres, sensor position in H relative to the axis
    phi, kappa = samples.platform_deg, samples.flip_deg
    rot = bench_rotation(phi, kappa)
    position_w = rot.apply(offset_h)
    return rot.apply(position_w @ g.T, inverse=True)


def write_fourflip(session: SimulatedSession, path, *, force: bool = False) -> tuple[Path, Path]:
    """Write the recording CSV and its truth side file ``<stem>.truth.json``.

    Raises
    ------
    FileExistsError
        If either file exists and ``force`` is False.
    """
    smp = session.samples
    columns = ["t_s", "flip_deg", "platform_deg"]
    data = [smp.t_s, smp.flip_deg, smp.platform_deg]
    formats = ["%.3f", "%.1f", "%.4f"]
    if smp.temp_c is not None:
        columns.append("temp_c")
        data.append(smp.temp_c)
        formats.append("%.3f")
    columns += list(session.channels)
    formats += ["%.7f"] * len(session.channels)
    data.append(session.outputs)
    if session.accel is not None:
        columns += ["ax", "ay", "az"]
        formats += ["%.6f"] * 3
        data.append(session.accel)
    table = np.column_stack(data)
    return write_with_truth(path, csv_text(columns, table, formats, session.metadata), session.truth, force=force)
