"""A simulated bench: a compass module on a turntable, an operator, and what the module sends.

The module's sensor is a four-flip session's (:func:`compass.sim.fourflip.simulate_fourflip`:
channels near X, Y, Z with its misalignment, offsets, gains, dip and noise) and its outputs come
from the same forward model (:func:`compass.sim.bench.bench_outputs`) at the true turntable angle
and flip.  The module also carries an accelerometer (g) and a gyro (rad/s, with a bias and a scale
error) aligned with the housing, and optionally sends the turntable's encoder as a column.

The operator (:class:`Operator`) does what the bench station's instruction says
(:class:`compass.station.session.Instruction` as a dict): puts the face asked for down, turns
the table once round from its mark back to it, or turns it to a stop, with a human's pace and
errors: stopping at the mark within ``mark_sigma_deg``, reading a graduation within
``read_half_width_deg``, and the mistakes asked for (``short_turn``: the first turn of flip 180
stops 60 deg short; ``wrong_face``: flip 90 is first made the wrong way round, -Y up).
Each mistake is made once; asked again, the operator does it right.

The module speaks one of the stream formats of real boards (``fmt``, :data:`RIG_FORMATS`): our line
protocol with a header (volts, as the four-flip simulation's sensor outputs); MotionCal's ``Raw:``
and ``Uni:`` lines (:mod:`compass.sim.stream_formats`: no time, no encoder, the field in uT: the
outputs divided by :data:`VOLTS_PER_UT`); or bare numbers (``csv``: :meth:`BenchRig.csv_columns`
space separated, the gyro in deg/s as much hobby firmware sends it).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..io.lines import format_line
from .bench import BenchPhysics, BenchSamples, bench_outputs
from .fourflip import simulate_fourflip

__all__ = ["Operator", "BenchRig", "MISTAKES", "RIG_FORMATS", "VOLTS_PER_UT"]

MISTAKES = ("short_turn", "wrong_face")
RIG_FORMATS = ("compass", "motioncal", "motioncal-raw", "csv")
VOLTS_PER_UT = 0.02
"""The four-flip simulation's nominal gain, volts per uT: a MotionCal board's outputs are the volts over it."""


@dataclass
class Operator:
    """How the simulated operator works.

    Attributes
    ----------
    turn_dps : float
        Peak turn rate, deg/s.
    flip_s : float
        Time to flip the cube, seconds.
    react_s : float
        Time before the operator acts on a new instruction, seconds.
    hold_s : float
        Still time at the mark before a turn, seconds.
    mark_sigma_deg : float
        Where a turn ends against the mark: normal, this sigma, degrees.
    read_half_width_deg : float
        A stop's error: uniform within +- this, degrees.
    mistakes : tuple of str
        From :data:`MISTAKES`.
    """

    turn_dps: float = 30.0
    flip_s: float = 3.0
    react_s: float = 0.5
    hold_s: float = 2.5
    mark_sigma_deg: float = 0.0
    read_half_width_deg: float = 0.0
    mistakes: tuple = ()
    made: set = field(default_factory=set)


class BenchRig:
    """The module on the turntable, in module time.

    Parameters
    ----------
    seed : int
        Seeds the sensor (as ``compass simulate fourflip --seed``), the noise and the operator.
    rate_hz : float
        Samples per second.
    noise_ut : float
        Channel noise, microtesla equivalent.
    operator : Operator
    gyro_bias_dps : float
        RMS of each gyro axis' constant bias, deg/s.
    gyro_scale_error : float
        RMS of each gyro axis' relative scale error.
    encoder_step_deg : float or None
        Send the turntable's angle as column ``encoder_column``, quantised to this step (0: exact).
    encoder_column : str
    accel_noise_g, gyro_noise_dps : float
        Per-sample white noise.
    fmt : str
        The stream format, one of :data:`RIG_FORMATS` (MotionCal's carry no encoder column).
    table_clockwise : bool
        The table's encoder and graduation count clockwise seen from above, against SPEC's turntable angle (a
        mistake the station must catch): the encoder column sends ``-phi``, and the operator finds stop ``m`` at
        the true angle ``-m``.

    Attributes
    ----------
    truth : dict
        The sensor's truth (directions, offsets, gains, dip, noise) as ``simulate_fourflip`` gives it.
    physics : BenchPhysics
    noise : ndarray, shape (c,)
        Channel noise in output units.
    """

    def __init__(self, *, seed: int = 0, rate_hz: float = 100.0, noise_ut: float = 0.15,
                 operator: Operator | None = None, gyro_bias_dps: float = 0.0, gyro_scale_error: float = 0.0,
                 encoder_step_deg: float | None = None, encoder_column: str = "enc", accel_noise_g: float = 0.002,
                 gyro_noise_dps: float = 0.05, fmt: str = "compass", table_clockwise: bool = False):
        if fmt not in RIG_FORMATS:
            raise ValueError(f"format {fmt!r}: expected one of {', '.join(RIG_FORMATS)}")
        if fmt.startswith("motioncal") and encoder_step_deg is not None:
            raise ValueError("MotionCal lines carry no encoder column: use the gyro, manual stops or a GRBL table")
        self.fmt = fmt
        self.table_sign = -1.0 if table_clockwise else 1.0
        session = simulate_fourflip(seed=seed, n_channels=3, noise_ut=noise_ut, step_deg=45.0)
        self.truth = session.truth
        self.physics: BenchPhysics = session.base_physics()
        self.channels = session.channels
        self.noise = np.asarray(session.truth["noise"])
        self.rate_hz = float(rate_hz)
        self.operator = operator or Operator()
        self.encoder_step_deg = encoder_step_deg
        self.encoder_column = encoder_column
        self.accel_noise_g = accel_noise_g
        self.gyro_noise = np.radians(gyro_noise_dps)
        rng = np.random.default_rng([seed, 0xB17])
        self.gyro_bias = np.radians(rng.normal(scale=gyro_bias_dps, size=3)) if gyro_bias_dps else np.zeros(3)
        self.gyro_scale = 1.0 + (rng.normal(scale=gyro_scale_error, size=3) if gyro_scale_error else np.zeros(3))
        self._rng = rng
        self._noise_rng = np.random.default_rng([seed, 0x5A3])
        self._segments: list = []  # (t0, t1, phi0, phi1, kappa0, kappa1)
        self._phi = float(rng.uniform(0.0, 360.0))  # where the table happens to be
        self._kappa = 0.0
        self._last_n = None
        self._sent = 0
        self.send_accel = True  # False: the module stops sending ax,ay,az (a changed header)
        self._clock_zero_s = 0.0  # the module's clock reads the rig's time less this (restart_clock)
        self.operator_turns = True  # False: a motor turns the table (turn_table); the operator only flips
        self.truth = {**self.truth, "gyro_bias_rad_s": self.gyro_bias.tolist(), "gyro_scale": self.gyro_scale.tolist()}

    # ---------------------------------------------------------------- operator
    def instruct(self, instruction: dict, t_s: float) -> None:
        """The operator reads an instruction at module time ``t_s`` (a repeated one is ignored)."""
        if instruction is None or instruction.get("n") == self._last_n:
            return
        self._last_n = instruction.get("n")
        op = self.operator
        start = max(t_s + op.react_s, self._segments[-1][1] if self._segments else 0.0)
        do = instruction.get("do")
        if do == "flip":
            target = float(instruction["flip_deg"])
            if target == 90.0 and self._mistake("wrong_face"):
                target = 270.0
            delta = (target - self._kappa + 180.0) % 360.0 - 180.0
            if abs(delta) > 1e-9:
                self._move(start, op.flip_s, 0.0, delta)
        elif do == "turn":
            if self._off_mark() > 2.0:
                to_mark = 360.0 - self._phi % 360.0
                start = self._move(start, self._turn_s(to_mark), to_mark, 0.0) + op.hold_s
            else:
                start += op.hold_s
            full = 360.0 + float(self._rng.normal(scale=op.mark_sigma_deg)) if op.mark_sigma_deg else 360.0
            if float(instruction["flip_deg"]) == 180.0 and self._mistake("short_turn"):
                full = 300.0
            self._move(start, self._turn_s(full), full, 0.0)
        elif do == "stop" and self.operator_turns:
            error = float(self._rng.uniform(-op.read_half_width_deg, op.read_half_width_deg))
            sign = self.table_sign  # the way the marks go up
            delta = (sign * (float(instruction["stop_deg"]) + error) - self._phi) * sign % 360.0
            delta = sign * (delta - 360.0 if delta > 350.0 else delta)  # a touch past the mark: back a little
            if abs(delta) > 1e-9:
                self._move(start, max(0.8, self._turn_s(delta)), delta, 0.0)

    def _mistake(self, name: str) -> bool:
        if name in self.operator.mistakes and name not in self.operator.made:
            self.operator.made.add(name)
            return True
        return False

    def _off_mark(self) -> float:
        p = self._phi % 360.0
        return min(p, 360.0 - p)

    def _turn_s(self, degrees: float) -> float:
        """Duration of an eased turn whose peak rate is the operator's ``turn_dps``."""
        return max(0.5, abs(degrees) * np.pi / 2.0 / self.operator.turn_dps)

    def _move(self, t0: float, duration: float, d_phi: float, d_kappa: float) -> float:
        t1 = t0 + duration
        self._segments.append((t0, t1, self._phi, self._phi + d_phi, self._kappa, self._kappa + d_kappa))
        self._phi += d_phi
        self._kappa += d_kappa
        return t1

    def turn_table(self, t_s: float, d_phi: float, rate_dps: float) -> float:
        """A motor turns the table by ``d_phi`` degrees, from ``t_s`` (or when the motion before ends),
        its peak rate ``rate_dps``; returns when it ends, module seconds."""
        start = max(t_s, self._segments[-1][1] if self._segments else 0.0)
        return self._move(start, max(0.05, abs(d_phi) * np.pi / 2.0 / rate_dps), d_phi, 0.0)

    def idle_at(self, t_s: float) -> bool:
        """Whether every scheduled motion has ended by ``t_s``."""
        return not self._segments or self._segments[-1][1] <= t_s

    # ---------------------------------------------------------------- the module
    def pose(self, t_s) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """True turntable angle and flip at times ``t_s`` and their rates (deg, deg, deg/s, deg/s)."""
        t = np.atleast_1d(np.asarray(t_s, float))
        phi = np.full(t.shape, np.nan)
        kappa = np.full(t.shape, np.nan)
        dphi = np.zeros(t.shape)
        dkappa = np.zeros(t.shape)
        first = self._segments[0] if self._segments else (np.inf, np.inf, self._phi, self._phi, self._kappa,
                                                            self._kappa)
        phi[:] = first[2]
        kappa[:] = first[4]
        for t0, t1, p0, p1, k0, k1 in self._segments:
            after = t >= t1
            phi[after], kappa[after] = p1, k1
            inside = (t >= t0) & (t < t1)
            if inside.any():
                u = (t[inside] - t0) / (t1 - t0)
                ease = 0.5 - 0.5 * np.cos(np.pi * u)
                slope = 0.5 * np.pi * np.sin(np.pi * u) / (t1 - t0)
                phi[inside] = p0 + (p1 - p0) * ease
                kappa[inside] = k0 + (k1 - k0) * ease
                dphi[inside] = (p1 - p0) * slope
                dkappa[inside] = (k1 - k0) * slope
        return phi, kappa, dphi, dkappa

    def measure(self, t_s) -> dict:
        """What the module measures at times ``t_s``: ``outputs`` (n, c), ``accel`` (n, 3) in g,
        ``gyro`` (n, 3) in rad/s, ``encoder_deg`` (n,) or None, and the truth ``phi_deg``, ``kappa_deg``."""
        t = np.atleast_1d(np.asarray(t_s, float))
        phi, kappa, dphi, dkappa = self.pose(t)
        n = len(t)
        samples = BenchSamples(phi, kappa, np.zeros(n, int))
        rng = self._noise_rng
        outputs = bench_outputs(self.physics, samples) + rng.normal(size=(n, len(self.noise))) * self.noise
        k = np.radians(kappa)
        up = np.column_stack([np.zeros(n), np.sin(k), np.cos(k)])  # Rx(kappa)^T z
        accel = up + self.accel_noise_g * rng.normal(size=(n, 3))
        omega = up * np.radians(dphi)[:, None] + np.outer(np.radians(dkappa), [1.0, 0.0, 0.0])
        gyro = omega * self.gyro_scale + self.gyro_bias + self.gyro_noise * rng.normal(size=(n, 3))
        encoder = None
        if self.encoder_step_deg is not None:
            encoder = np.mod(self.table_sign * phi, 360.0)
            if self.encoder_step_deg > 0:
                encoder = np.mod(np.round(encoder / self.encoder_step_deg) * self.encoder_step_deg, 360.0)
        return {"outputs": outputs, "accel": accel, "gyro": gyro, "encoder_deg": encoder, "phi_deg": phi,
                "kappa_deg": kappa}

    def restart_clock(self, t_s: float) -> None:
        """The module resets at rig time ``t_s``: the ``t_s`` it sends starts from 0 again (the table, the
        operator and the noise go on in the rig's time)."""
        self._clock_zero_s = float(t_s)

    def columns(self) -> list[str]:
        """The module's header columns."""
        extra = [self.encoder_column] if self.encoder_step_deg is not None else []
        accel = ["ax", "ay", "az"] if self.send_accel else []
        return ["t_s", "seq", *self.channels, *accel, "gx", "gy", "gz", *extra]

    def csv_columns(self) -> tuple[str, ...]:
        """The cells of the ``csv`` format's lines, as ``--columns`` names them (the gyro in deg/s)."""
        return tuple(n for n in self.columns() if n != "seq")

    def lines(self, t_s) -> bytes:
        """The lines of samples at rig times ``t_s``, in order, in the rig's format (module docstring); the ``t_s`` sent
        is the module's clock (:meth:`restart_clock`)."""
        m = self.measure(t_s)
        if self.fmt.startswith("motioncal"):
            from .stream_formats import sample_lines

            return b"".join(sample_lines(self.fmt, np.atleast_1d(t_s), m["outputs"] / VOLTS_PER_UT, m["accel"],
                                         m["gyro"]))
        if self.fmt == "csv":
            parts = [np.atleast_1d(t_s)[:, None] - self._clock_zero_s, m["outputs"]] + [m["accel"]] * self.send_accel
            parts.append(np.degrees(m["gyro"]))
            if m["encoder_deg"] is not None:
                parts.append(m["encoder_deg"][:, None])
            rows = np.column_stack(parts)
            self._sent += len(rows)
            return b"".join((" ".join(f"{v:.7g}" for v in row) + "\r\n").encode("ascii") for row in rows)
        parts = [m["outputs"]] + [m["accel"]] * self.send_accel + [m["gyro"]]
        if m["encoder_deg"] is not None:
            parts.append(m["encoder_deg"][:, None])
        rows = np.column_stack(parts)
        c = len(self.channels)
        imu = 6 if self.send_accel else 3
        fmt = ",".join(["%.7g"] * c + ["%.6f"] * imu + ["%.4f"] * (rows.shape[1] - c - imu))
        out = []
        for t, row in zip(np.atleast_1d(t_s), rows):
            out.append(format_line([f"{t - self._clock_zero_s:.4f}", self._sent, fmt % tuple(row)]))
            self._sent += 1
        return b"".join(out)

    def header(self) -> bytes:
        """The header line of our protocol (nothing in the other formats)."""
        return format_line(self.columns()) if self.fmt == "compass" else b""


def drive(rig: BenchRig, station, stream, *, max_s: float = 900.0, block_s: float = 0.1, on_block=None) -> float:
    """Run a station against the rig in lock step (module time, no real time): the operator reads
    the station's instruction every block, the module's lines go through the station's stream,
    received at the module time of the block's last sample (what dates a stream without ``t_s``).

    Parameters
    ----------
    rig : BenchRig
    station : compass.station.Station
    stream : compass.station.StationStream
    max_s : float
        Module time after which the session is abandoned, seconds.
    block_s : float
        Samples sent per step, seconds of module time.
    on_block : callable, optional
        ``on_block(rig, t_s)`` before each block (a test changes the module mid-session).

    Returns
    -------
    float
        Module time at the end, seconds.
    """
    n = max(1, int(round(block_s * rig.rate_hz)))
    k = 0
    t = 0.0
    next_header = 0.0
    while not station.finished and t < max_s:
        rig.instruct(station.instruction.to_json(), t)
        if on_block is not None:
            on_block(rig, t)
            n = max(1, int(round(block_s * rig.rate_hz)))
        times = t + np.arange(n) / rig.rate_hz
        data = rig.lines(times)
        if t >= next_header:
            data = rig.header() + data
            next_header = t + 1.0
        for reading in stream.feed(data, times[-1]):
            station.feed(reading)
        t = times[-1] + 1.0 / rig.rate_hz
        k += 1
    return t
