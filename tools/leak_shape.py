"""The tilt's transfer functions on paper (issue 22): how much hand motion each design lets into the inclination.

Run: ``python tools/leak_shape.py [DATA_DIR] [--trials 01,32] [--no-data] [--write-docs]``.

Model (one horizontal axis, continuous time, small angles; docs/benchmarks.md, "The leak's shape on paper").  The
accelerometer, low-passed in the gyro-propagated inertial frame by ``H`` (ours: first order, 2 s), measures the tilt
error ``e`` of the gyro's attitude with two errors: the motion acceleration it leaves, ``H a`` (the *leak*), and the
gyro's drift over its memory, ``(1 - H) theta``.  The Kalman filter turns that measurement into its estimate by a
transfer ``K(s)`` fixed by its model (the gyro's process noise against the leak's), so the attitude error is

    ``(1 - L) theta + L a``,   ``L = K H``  (ours),   ``L = H2``  (VQF: its Butterworth, ``tauAcc`` 3 s, applied outright).

``L`` is the design's whole low-pass: ``|L|`` at the hand's periods (0.3-6 s) is the motion it lets into the tilt,
``|1 - L|`` at long periods the gyro drift it passes, and ``L ~ 1 - a1 s`` its mean age ``a1``.  Every design is
compared by those three.  The designs: today's (the leak white noise of density ``2 tau_v sigma^2``,
``FilterConfig.motion_time_s`` = ``tau_v``); the leak as a *shaped* process in the state (a second-order Gauss-Markov
band-pass at the motion's ``1 / tau_v``, or the first-order low-pass's own dynamics on a Gauss-Markov hand velocity
of correlation ``tau_v``), its variance the one the filter reads; the gyro's scale error as a Gauss-Markov *rate*
error of correlation ``_SCALE_CORRELATION_S`` (1 s) with today's low-frequency density (the equivalent augmentation
on the gyro's side); VQF's Butterworth.  The steady-state gain of each is the continuous algebraic Riccati
equation's (scipy).  Four scenarios: the turn rate and the leak as the filter reads it (docs/benchmarks.md:
"The disturbed and attached-magnet inclination, by time scale" and "Inclination in turns"), with the designs at
their own model's intensities and again with each scaled to today's mean age (the shape alone).

``--data`` (default on; ``--no-data`` skips it): a truth-based check of the leak alone on BROAD: per trial, the
horizontal motion acceleration (the accelerometer put into the world by the reference attitude, less gravity and its
offset at the initial rest, as ``tools/bench_broad.py --leak``) through each design's ``L`` (the trial's rms turn
rate and its truth-based leak as the scenario), RMS per axis over the movement rows, deg.  An LTI stand-in for the
adaptive filter: the sizes, not the filter's result.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
from scipy import signal
from scipy.linalg import solve_continuous_are, solve_continuous_lyapunov

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

from _doc_table import markdown_table, parse_args, publish  # noqa: E402

TAU_S = 2.0  # FilterConfig.accel_time_constant_s: our first-order inertial low-pass
MOTION_TIME_S = 0.5  # FilterConfig.motion_time_s: the leak's correlation time in today's model
SCALE_TIME_S = 1.0  # compass.filter._records._SCALE_CORRELATION_S: the scale error's correlation
SCALE_ERROR = 0.005  # FilterConfig.gyro_scale_error
GYRO_VAR = 3e-4**2  # FilterConfig.gyro_noise squared, rad^2/s
RATE_HZ = 285.714  # BROAD's
ACCEL_DENSITY = 0.005**2 / RATE_HZ  # FilterConfig.accel_noise as a density, rad^2 s
VQF_TAU_S = 3.0  # VQF's tauAcc
LEAK_PERIODS_S = (0.5, 1.0, 2.0, 3.0, 6.0)
DRIFT_PERIODS_S = (10.0, 30.0)
SCENARIOS = {  # name: (rms turn rate rad/s, the leak per axis as the filter reads it, deg)
    "hand-turned magnets 32-34": (3.0, 0.93),
    "fast turns 28, 30": (6.0, 1.5),
    "slow rotation 01": (1.7, 0.44),
    "slow translation 10": (0.9, 1.13),
}


def kalman_transfer(a, g, q, c, r) -> tuple[np.ndarray, np.ndarray]:
    """The steady-state Kalman filter's transfer from its measurement to its estimate of state 0, ``(num, den)``.

    Parameters
    ----------
    a, g, q, c : array_like
        ``x' = a x + g w`` (``E w w^T = q delta``), ``y = c x + v``, ``c`` one row.
    r : float
        ``E v v = r delta``, the measurement's white noise density.
    """
    a, g, q, c = (np.atleast_2d(np.asarray(v, float)) for v in (a, g, q, c))
    p = solve_continuous_are(a.T, c.T, g @ q @ g.T, np.array([[r]]))
    k = p @ c.T / r
    num, den = signal.ss2tf(a - k @ c, k, np.eye(len(a))[:1], np.zeros((1, 1)))
    return np.ravel(num), np.ravel(den)


def _rate_var(turn_rad_s: float) -> float:
    return (SCALE_ERROR * turn_rad_s) ** 2


def today(turn_rad_s: float, leak_var: float, scale: float = 1.0):
    """Today's ``K``: the tilt a random walk (gyro white noise and scale error, ``FilterCoefficients.scale_var``),
    the leak white of density ``2 tau_v sigma^2`` (with the accelerometer's own)."""
    q = (GYRO_VAR + _rate_var(turn_rad_s) * SCALE_TIME_S) * scale
    return kalman_transfer([[0.0]], [[1.0]], [[q]], [[1.0]], ACCEL_DENSITY + 2.0 * MOTION_TIME_S * leak_var)


def band_pass_leak(turn_rad_s: float, leak_var: float, scale: float = 1.0, zeta: float = 2**-0.5):
    """The leak a second-order Gauss-Markov band-pass at ``w0 = 1 / tau_v`` (``l = p'``, ``p'' + 2 zeta w0 p' + w0^2 p
    = w``; ``var p' = W / (4 zeta w0)`` set to ``leak_var``) in the state."""
    w0 = 1.0 / MOTION_TIME_S
    q = (GYRO_VAR + _rate_var(turn_rad_s) * SCALE_TIME_S) * scale
    a = [[0, 0, 0], [0, 0, 1], [0, -w0 * w0, -2 * zeta * w0]]
    g = [[1, 0], [0, 0], [0, 1]]
    return kalman_transfer(a, g, np.diag([q, 4 * zeta * w0 * leak_var]), [[1.0, 0.0, 1.0]], ACCEL_DENSITY)


def low_pass_leak(turn_rad_s: float, leak_var: float, scale: float = 1.0):
    """The leak as the first-order low-pass's own dynamics: ``l = (v - u) / tau``, ``u' = (v - u) / tau``, ``v`` a
    Gauss-Markov hand velocity of correlation ``tau_v`` (its noise set so that ``var l = leak_var``)."""
    q = (GYRO_VAR + _rate_var(turn_rad_s) * SCALE_TIME_S) * scale
    sub = np.array([[-1.0 / MOTION_TIME_S, 0.0], [1.0 / TAU_S, -1.0 / TAU_S]])
    unit = solve_continuous_lyapunov(sub, -np.array([[1.0, 0.0], [0.0, 0.0]]))
    out = np.array([1.0 / TAU_S, -1.0 / TAU_S])
    a = np.zeros((3, 3))
    a[1:, 1:] = sub
    g = [[1, 0], [0, 1], [0, 0]]
    return kalman_transfer(a, g, np.diag([q, leak_var / (out @ unit @ out)]), [[1.0, 1.0 / TAU_S, -1.0 / TAU_S]],
                           ACCEL_DENSITY)


def rate_error(turn_rad_s: float, leak_var: float, scale: float = 1.0):
    """The scale error a Gauss-Markov rate error of correlation ``SCALE_TIME_S`` in the state (``e' = r``, ``r' = -r /
    T + w``, ``var r = s^2 |w|^2 / 2``: today's low-frequency density ``s^2 |w|^2 T``), the leak white as today."""
    a = [[0.0, 1.0], [0.0, -1.0 / SCALE_TIME_S]]
    q = np.diag([GYRO_VAR * scale, _rate_var(turn_rad_s) / SCALE_TIME_S * scale])
    return kalman_transfer(a, np.eye(2), q, [[1.0, 0.0]], ACCEL_DENSITY + 2.0 * MOTION_TIME_S * leak_var)


DESIGNS = {"today (white leak)": today, "leak: band-pass GM": band_pass_leak,
           "leak: the low-pass's dynamics": low_pass_leak, "scale error: GM rate": rate_error}


def butterworth(tau_s: float = VQF_TAU_S) -> tuple[np.ndarray, np.ndarray]:
    """VQF's second-order Butterworth low-pass (cut-off ``sqrt 2 / (2 pi tau)`` Hz, mean age ``tau``), ``(num, den)``."""
    wc = math.sqrt(2.0) / tau_s
    return np.array([wc * wc]), np.array([1.0, math.sqrt(2.0) * wc, wc * wc])


def whole(k) -> tuple[np.ndarray, np.ndarray]:
    """``L = K H``: the Kalman transfer after our first-order inertial low-pass."""
    return np.polymul(k[0], [1.0]), np.polymul(k[1], [TAU_S, 1.0])


def response(tf, periods_s) -> np.ndarray:
    """The complex response of ``(num, den)`` at ``periods_s``."""
    return signal.freqs(tf[0], tf[1], worN=2.0 * np.pi / np.asarray(periods_s, float))[1]


def mean_age_s(tf) -> float:
    """``a1`` of ``L ~ 1 - a1 s``: the DC group delay, s."""
    w = 1e-4
    return float(-np.angle(signal.freqs(tf[0], tf[1], worN=[w])[1][0]) / w)


def at_age(design, turn_rad_s: float, leak_var: float, age_s: float):
    """``design``'s ``L`` with its process noise scaled so that its mean age is ``age_s`` (the shape alone)."""
    from scipy.optimize import brentq

    log_scale = brentq(lambda x: mean_age_s(whole(design(turn_rad_s, leak_var, 10.0**x))) - age_s, -4.0, 4.0)
    return whole(design(turn_rad_s, leak_var, 10.0**log_scale))


def paper_table() -> str:
    """Every scenario's designs: mean age, ``|L|`` at :data:`LEAK_PERIODS_S`, ``|1 - L|`` at :data:`DRIFT_PERIODS_S`."""
    header = (["scenario", "design", "mean age s"] + [f"\\|L\\| {p:g} s" for p in LEAK_PERIODS_S]
              + [f"\\|1 - L\\| {p:g} s" for p in DRIFT_PERIODS_S])
    rows = []

    def add(scenario, name, tf):
        leak, drift = np.abs(response(tf, LEAK_PERIODS_S)), np.abs(1.0 - response(tf, DRIFT_PERIODS_S))
        rows.append([scenario, name, f"{mean_age_s(tf):.2f}"] + [f"{v:.3f}" for v in leak] + [f"{v:.2f}" for v in drift])

    add("any", "VQF (Butterworth 3 s, outright)", butterworth())
    for scenario, (turn, leak_deg) in SCENARIOS.items():
        var = math.radians(leak_deg) ** 2
        base = whole(today(turn, var))
        label = f"{scenario} ({turn:g} rad/s, {leak_deg:g} deg)"
        for name, design in DESIGNS.items():
            add(label, name, whole(design(turn, var)))
        for name, design in list(DESIGNS.items())[1:]:
            add(label, f"{name}, at today's mean age", at_age(design, turn, var, mean_age_s(base)))
        add(label, "Butterworth at today's mean age", butterworth(mean_age_s(base)))
    return markdown_table(header, rows)


def data_table(data: Path, wanted: list[str]) -> str:
    """Truth-based: each trial's horizontal motion through each design's ``L`` (LTI, the trial's rms turn rate and
    truth-based first-order leak as its scenario), RMS per axis over the movement rows, deg."""
    from scipy.spatial.transform import Rotation

    from compass.io.broad import read_broad

    header = ["trial", "rms \\|w\\| rad/s", "leak of the 2 s low-pass"] + list(DESIGNS) + ["VQF"]
    rows = []
    for path in sorted(data.glob("*.mat")):
        if wanted and not any(path.name.startswith(p) for p in wanted):
            continue
        trial = read_broad(path)
        ok = trial.ref_valid & np.all(np.isfinite(trial.ref_quat_enu), axis=1)
        index = np.maximum.accumulate(np.where(ok, np.arange(len(ok)), 0))
        index[:np.argmax(ok)] = np.argmax(ok)
        world = Rotation.from_quat(trial.ref_quat_enu[index], scalar_first=True).apply(trial.accel_m_s2) / 9.81
        motion = world[:, :2] - world[: max(1, int(trial.rate_hz)), :2].mean(axis=0)
        rows_used = trial.movement

        def through(tf):
            out = _lsim(tf, motion, trial.rate_hz)
            return float(np.degrees(np.sqrt(np.mean(out[rows_used] ** 2))))

        turn = float(np.sqrt(np.mean(np.sum(trial.gyro_rad_s[rows_used] ** 2, axis=1))))
        first = through(whole(([1.0], [1.0])))  # H alone
        var = math.radians(first) ** 2
        cells = [through(whole(design(turn, var))) for design in DESIGNS.values()] + [through(butterworth())]
        rows.append([trial.name[:36], f"{turn:.1f}", f"{first:.2f}"] + [f"{v:.2f}" for v in cells])
        print(f"  {trial.name[:36]}: " + ", ".join(rows[-1][1:]), flush=True)
    return markdown_table(header, rows)


def _lsim(tf, x: np.ndarray, rate_hz: float) -> np.ndarray:
    """``tf`` applied to each column of ``x`` (sampled at ``rate_hz``), discretised by the bilinear transform."""
    b, a = signal.bilinear(tf[0], tf[1], fs=rate_hz)
    return signal.lfilter(b, a, x, axis=0)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data", nargs="?", default=str(ROOT.parent / "shared" / "data" / "broad"))
    parser.add_argument("--trials", default="", help="comma-separated trial number prefixes (default: all)")
    parser.add_argument("--no-data", action="store_true", help="the transfer functions only (no BROAD trial)")
    args = parse_args(parser, argv)
    publish(args, "docs/benchmarks.md", "leak_shape.paper", paper_table(),
            "one horizontal axis, steady-state gains; `L` the design's whole low-pass from motion to tilt")
    if args.no_data:
        return 0
    data = Path(args.data)
    if not any(data.glob("*.mat")):
        print(f"no BROAD trials in {data}", file=sys.stderr)
        return 2
    print("\ntruth-based leak through each design's L (LTI stand-in), RMS per axis, deg")
    publish(args, "docs/benchmarks.md", "leak_shape.data",
            data_table(data, [p for p in args.trials.split(",") if p]),
            "the horizontal motion (truth) through each design's `L`, RMS per axis over the movement rows, deg")
    return 0


if __name__ == "__main__":
    sys.exit(main())
