"""BROAD's gyro against its optical truth: scale and cross-axis errors, and how much of the turn is about the vertical.

Run: ``python tools/bench_gyro_axes.py [DATA_DIR]`` (default ``../shared/data/broad``; deterministic, no seed).

Issue 22's question: does a gyro scale error tilt the estimate in the hand-turned trials, or only turn its heading?
A scale error ``s_i`` on housing axis ``i`` turns the attitude about that axis by ``s_i w_i dt``; a cross-axis error
``c_ij`` turns it about axis ``i`` by ``c_ij w_j dt``, perpendicular to the turn.  The cross-axis part of ``E`` is
split in two: its symmetric part (the gyro's axes not orthogonal: an error of the gyro) and its antisymmetric part
(a rotation ``theta`` with ``E = [theta]x`` transposed: the gyro's axes turned against the truth's frame, which is the
gyro turned against the accelerometer, a tilting error, or the optical markers turned against the IMU, which no
filter feels and the truth cannot tell apart).  With the turn about the vertical, a
scale error leaves the tilt alone and a cross-axis error tilts it.  So the filter's isotropic scale-error noise
(``FilterConfig.gyro_scale_error`` times ``|w|^2`` on every axis) is the model of errors of both kinds of one size;
a per-axis model (``R diag(w^2) R^T``) would be right only if the cross-axis errors were much smaller.

Per trial: the gyro regressed on the truth's body rate, ``g = (I + E) w + b`` (least squares over the samples turning
faster than 0.5 rad/s where the two agree within 0.3 rad/s, both as 0.1 s moving means; the truth's rate from
consecutive reference attitudes, ``Log(R_k^T R_k+1) / dt``), and the RMS of ``E``'s diagonal (scale) and of its six
symmetric and antisymmetric off-diagonal pairs, in percent; then the share of ``|w|^2`` about the world vertical (the part a
scale error turns the heading only).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.ndimage import uniform_filter1d
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from compass.io.broad import read_broad  # noqa: E402

_FAST_RAD_S = 0.5  # turns slower than this carry the rate noise, not the scale
_AGREE_RAD_S = 0.3  # the truth's gaps and jumps: samples where the rates differ more are left out
_MEAN_S = 0.1  # moving mean of both rates, s (the optical truth's differentiation noise)


def gyro_errors(trial) -> tuple[np.ndarray, float, float] | None:
    """``(E, vertical share, rms rate)`` of one trial: the 3x3 error matrix ``E`` (``g = (I + E) w + b``), the share
    of ``|w|^2`` about the world vertical, and the RMS turn rate in rad/s, over the fast samples; None if under 100."""
    q = np.asarray(trial.ref_quat_enu, dtype=float)
    ok = np.all(np.isfinite(q), axis=1)
    r = Rotation.from_quat(np.where(ok[:, None], q, [1.0, 0.0, 0.0, 0.0]), scalar_first=True)
    dt = 1.0 / trial.rate_hz
    truth = (r[:-1].inv() * r[1:]).as_rotvec() / dt
    gyro = (trial.gyro_rad_s[:-1] + trial.gyro_rad_s[1:]) / 2.0  # the gyro at the step's middle, as the truth's rate
    n = max(1, round(_MEAN_S * trial.rate_hz))
    truth, gyro = uniform_filter1d(truth, n, axis=0), uniform_filter1d(gyro, n, axis=0)
    use = (ok[:-1] & ok[1:] & (np.linalg.norm(truth, axis=1) > _FAST_RAD_S)
           & (np.linalg.norm(truth - gyro, axis=1) < _AGREE_RAD_S))
    if use.sum() < 100:
        return None
    design = np.column_stack([truth[use], np.ones(use.sum())])
    coef = np.linalg.lstsq(design, gyro[use], rcond=None)[0]
    world = r[:-1][use].apply(truth[use])
    w2 = np.sum(world**2, axis=1)
    return coef[:3].T - np.eye(3), float(np.sum(world[:, 2] ** 2) / np.sum(w2)), float(np.sqrt(np.mean(w2)))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data", nargs="?", default=str(ROOT.parent / "shared" / "data" / "broad"))
    args = parser.parse_args(argv)
    paths = sorted(Path(args.data).glob("*.mat"))
    if not paths:
        print(f"{args.data}: no BROAD .mat files", file=sys.stderr)
        return 2
    print("trial                                   scale %  non-orthogonal %  rotation %  vertical share of |w|^2  "
          "rms |w| rad/s")
    for path in paths:
        print(f"  reading {path.name}", file=sys.stderr)
        found = gyro_errors(read_broad(path))
        if found is None:
            print(f"{path.stem[:38]:38s}  fewer than 100 fast samples")
            continue
        e, vertical, rate = found
        sym, rot = (e + e.T) / 2.0, (e - e.T) / 2.0
        upper = np.triu_indices(3, 1)
        print(f"{path.stem[:38]:38s}  {100 * np.sqrt(np.mean(np.diag(e) ** 2)):7.2f}  "
              f"{100 * np.sqrt(np.mean(sym[upper] ** 2)):16.2f}  {100 * np.sqrt(np.mean(rot[upper] ** 2)):10.2f}  "
              f"{vertical:23.2f}  {rate:13.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
