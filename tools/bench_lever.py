"""Issue 22, the lever arm: does a constant housing-frame lever arm explain the motion the inertial low-pass leaves?

Run: ``python tools/bench_lever.py [DATA_DIR] [--trials 01,28]`` (default data: ``../shared/data/broad``).  A check
with the truth (BROAD's optical attitude), never a filter: per trial, the body-frame motion acceleration
``a_H = f_H - R^T (0, 0, g)`` (``R = R_ENU<-H`` the reference, less the world-frame specific force's mean over the
first second of the initial rest: the accelerometer's own offset) is fitted by least squares on the moving samples as
``(w x (w x r) + dw/dt x r) + c``: a constant lever arm ``r`` in H from a fixed rotation centre, ``c`` a constant
offset (both sides low-passed alike, a 5 Hz Butterworth forward and back, as the gyro's derivative needs).  Printed:

- ``r`` (cm) fitted on the whole trial, on its first and second halves, and its share of the body-frame motion
  acceleration's variance explained (whole-trial fit; and the second half with the first half's ``r``);
- the horizontal leak of the first-order inertial low-pass (``FilterConfig`` default time constant): the motion
  acceleration put into the world and low-passed there, over g, deg RMS per axis over the scored rows; and what is
  left after subtracting the lever arm's own leftover ``(v - LP v) / tau``, ``v = R (w x r)`` (no differentiation),
  with ``r`` from the whole trial, from the other half (first half's ``r`` on the second half and back), and the
  mean ``r`` of the other trials (leave one out).

With ``--filter``: the filter itself (bench_broad's pipeline, ``FilterConfig`` defaults and ``lever_arm=True``, the
arm fitted as it runs), the inclination RMS of its output and of its low-pass's direction applied outright (the
tilt's measurement, the lever arm's leftover taken out), deg, over the scored rows.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.signal import butter, filtfilt, lfilter
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

from compass.filter import FilterConfig  # noqa: E402
from compass.io.broad import read_broad  # noqa: E402

GRAVITY = 9.81
SMOOTH_HZ = 5.0  # both sides of the fit low-passed at this corner, Hz
MOVING_RATE = 0.5  # rows fitted: scored, with a reference, turning faster than this, rad/s


def skew(v: np.ndarray) -> np.ndarray:
    """``[v]x`` per row, shape (n, 3, 3)."""
    z = np.zeros(len(v))
    return np.stack([np.stack([z, -v[:, 2], v[:, 1]], 1), np.stack([v[:, 2], z, -v[:, 0]], 1),
                     np.stack([-v[:, 1], v[:, 0], z], 1)], 1)


def prepared(trial):
    """Reference ``R_ENU<-H`` (gaps held), body-frame motion acceleration (m/s^2), the lever's matrix
    ``M = [dw/dt]x + [w]x^2`` (1/s^2) and the motion acceleration, both smoothed alike, and the rows to fit."""
    ok = trial.ref_valid
    index = np.maximum.accumulate(np.where(ok, np.arange(len(ok)), 0))
    index[:np.argmax(ok)] = np.argmax(ok)
    ref = Rotation.from_quat(trial.ref_quat_enu[index], scalar_first=True)
    world = ref.apply(trial.accel_m_s2)
    world -= world[: max(1, int(trial.rate_hz))].mean(axis=0)  # gravity and the offset: the first second is at rest
    body = ref.inv().apply(world)
    w = trial.gyro_rad_s
    b, a = butter(2, SMOOTH_HZ / (trial.rate_hz / 2.0))
    ws = filtfilt(b, a, w, axis=0)
    dw = np.gradient(ws, 1.0 / trial.rate_hz, axis=0)
    sw = skew(ws)
    m = skew(dw) + sw @ sw
    rows = trial.movement & ok & (np.linalg.norm(ws, axis=1) > MOVING_RATE)
    return ref, world, m, filtfilt(b, a, body, axis=0), rows


def fit(m: np.ndarray, body: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares ``r`` (m) and a constant offset over ``rows``; the share of the variance explained."""
    n = int(rows.sum())
    design = np.concatenate([m[rows], np.broadcast_to(np.eye(3), (n, 3, 3))], axis=2).reshape(3 * n, 6)
    y = body[rows].reshape(-1)
    x = np.linalg.lstsq(design, y, rcond=None)[0]
    return x[:3], explained(m, body, rows, x[:3])


def explained(m, body, rows, r) -> float:
    """Share of the body-frame motion acceleration's variance (about its mean) the lever arm ``r`` explains."""
    y = body[rows] - body[rows].mean(axis=0)
    e = y - (m[rows] @ r - (m[rows] @ r).mean(axis=0))
    return float(1.0 - np.sum(e**2) / np.sum(y**2))


def leak_deg(trial, ref, world, r, rows) -> float:
    """Horizontal leak of the first-order inertial low-pass less the lever arm's ``(v - LP v) / tau``, deg RMS per
    axis over ``rows``."""
    tau = FilterConfig(field_norm=1.0, dip_deg=0.0, mag_noise=1.0).accel_time_constant_s
    alpha = -np.expm1(-1.0 / (trial.rate_hz * tau))

    def low_pass(x):
        return lfilter([alpha], [1.0, alpha - 1.0], x, axis=0)

    v = ref.apply(np.cross(trial.gyro_rad_s, r))
    left = low_pass(world) - (v - low_pass(v)) / tau
    return float(np.degrees(np.sqrt(np.mean(left[rows, :2] ** 2) / GRAVITY**2)))


def filter_check(files) -> int:
    """Print, per trial, the inclination RMS of the filter's output and of its low-pass's direction, lever arm off
    and on (:func:`bench_broad.low_pass_inclination`)."""
    from bench_broad import low_pass_inclination

    print("inclination RMS over the scored rows, deg: the filter's output off / on, its low-pass's direction off / on "
          "(lever_arm False / True)")
    for f in files:
        trial = read_broad(f)
        runs = [low_pass_inclination(trial, {"lever_arm": on})[1] for on in (False, True)]
        rms = {k: [float(np.sqrt(np.mean(r[k] ** 2))) for r in runs] for k in ("ours", "low-pass direction")}
        print(f"  {trial.name[:34]:34s} " + "   ".join(f"{a:.3f} / {b:.3f}" for a, b in rms.values()), flush=True)
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data", nargs="?", default=str(ROOT.parent / "shared" / "data" / "broad"))
    parser.add_argument("--trials", default="", help="comma-separated trial number prefixes (default: all)")
    parser.add_argument("--filter", action="store_true",
                        help="the filter's output and low-pass direction, lever arm off and on, instead of the fit")
    args = parser.parse_args(argv)
    wanted = [p for p in args.trials.split(",") if p]
    files = [f for f in sorted(Path(args.data).glob("*.mat"))
             if not wanted or any(f.name.startswith(p) for p in wanted)]
    if args.filter:
        return filter_check(files)
    data, arms = {}, {}
    for f in files:
        trial = read_broad(f)
        ref, world, m, body, rows = prepared(trial)
        half = np.arange(len(rows)) < np.flatnonzero(rows).mean()
        r, share = fit(m, body, rows)
        r1, _ = fit(m, body, rows & half)
        r2, _ = fit(m, body, rows & ~half)
        data[trial.name] = (trial, ref, world, m, body, rows, half, r, r1, r2, share)
        arms[trial.name] = r
    print("lever arm r in H, cm (whole / first half / second half); variance share explained (whole fit, second "
          "half with the first's r); horizontal leak of the first-order low-pass, deg RMS per axis over the scored "
          "rows: none removed / r whole / r other half / mean r of the other trials")
    for name, (trial, ref, world, m, body, rows, half, r, r1, r2, share) in data.items():
        scored = trial.movement & trial.ref_valid
        cross = explained(m, body, rows & ~half, r1)
        other = np.mean([a for k, a in arms.items() if k != name], axis=0) if len(arms) > 1 else np.zeros(3)
        halves = (leak_deg(trial, ref, world, r2, scored & half) ** 2
                  + leak_deg(trial, ref, world, r1, scored & ~half) ** 2)
        leaks = (leak_deg(trial, ref, world, np.zeros(3), scored), leak_deg(trial, ref, world, r, scored),
                 float(np.sqrt(halves / 2.0)), leak_deg(trial, ref, world, other, scored))
        cm = " / ".join("(" + ", ".join(f"{100 * x:5.1f}" for x in a) + ")" for a in (r, r1, r2))
        print(f"  {name[:34]:34s} {cm}  {share:5.2f} {cross:5.2f}  " + " / ".join(f"{x:.2f}" for x in leaks))
    return 0


if __name__ == "__main__":
    sys.exit(main())
