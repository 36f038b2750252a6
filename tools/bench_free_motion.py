"""Benchmark the tumble calibration beside peers, on simulated truth and on real recordings.

Peers: a plain algebraic ellipsoid fit (general quadric ``x^T A x + b.x = 1`` by linear least
squares, written here) and circuitpython-mag-cal (``mag_cal.Sensor.fit_ellipsoid``) when installed.
Metrics: on simulated tumbles, hard-iron error relative to |B|, soft-iron shape error (Frobenius,
det-1 matrices), misalignment error and the tilt-compensated heading error; on real data, the |B|
coefficient of variation and the spread (std) of the field-gravity angle over quasi-static
samples (``||a| - 1 g| < 0.02``), before and after.  Run: ``python tools/bench_free_motion.py``.
"""

from __future__ import annotations

from itertools import combinations_with_replacement
from pathlib import Path

import numpy as np
from scipy.io import loadmat
from scipy.spatial.transform import Rotation

from calibrate.tumble import calibrate_tumble, field_gravity_angles, static_mask
from compass.frames import heading_pitch_roll, world_field
from compass.sample_check import new_readings
from compass.sim.tumble import simulate_tumble

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def algebraic_fit(x):
    """General quadric fit; returns (h, T) with calibrated = (x - h) @ T.T, or None if not an ellipsoid."""
    d = np.column_stack([x**2, 2 * x[:, [0]] * x[:, [1]], 2 * x[:, [0]] * x[:, [2]], 2 * x[:, [1]] * x[:, [2]], 2 * x])
    c, *_ = np.linalg.lstsq(d, np.ones(len(x)), rcond=None)
    a = np.array([[c[0], c[3], c[4]], [c[3], c[1], c[5]], [c[4], c[5], c[2]]])
    h = -np.linalg.solve(a, c[6:9])
    k = 1 + h @ a @ h
    w, v = np.linalg.eigh(a / k)
    if np.any(w <= 0):
        return None
    t = (v * np.sqrt(w)) @ v.T
    return h, t / np.cbrt(np.linalg.det(t))


def magcal_fit(x):
    """circuitpython-mag-cal's ellipsoid, as (h, T); None if not installed or not an ellipsoid."""
    try:
        from mag_cal.sensor import Sensor
    except ImportError:
        return None
    s = Sensor()
    s.fit_ellipsoid(np.array(x, dtype=float))
    t = np.real(s.transform).T
    if not np.all(np.isfinite(t)) or np.linalg.det(t) <= 0 or np.any(np.linalg.eigvalsh((t + t.T) / 2) <= 0):
        return None
    return np.asarray(s.centre).ravel(), t / np.cbrt(np.linalg.det(t))


def metrics(m, a):
    """(|B| CV %, field-gravity angle std deg over quasi-static samples)."""
    n = np.linalg.norm(m, axis=1)
    st = static_mask(a)
    return 100 * n.std() / n.mean(), float(np.std(field_gravity_angles(m, a)[st]))


def orientation_features(u, degree):
    """Monomials of the columns of ``u`` up to total ``degree`` (a smooth function of them)."""
    cols = [np.ones(len(u))]
    for d in range(1, degree + 1):
        cols += [np.prod(u[:, c], axis=1) for c in combinations_with_replacement(range(u.shape[1]), d)]
    return np.column_stack(cols)


def calibration_floor(m, a, degree=3):
    """What no further calibration can remove from the field-gravity angle spread (deg, quasi-static samples).

    A further calibration of either sensor (offsets, gains, soft iron, a rotation between them,
    nonlinearity) turns each sensor's direction by a smooth function of that direction:
    ``u_m -> u_m + F(u_m)``, ``u_a -> u_a + G(u_a)``.  To first order the angle ``theta`` then
    changes by ``-(p_m . F(u_m) + p_a . G(u_a)) / sin(theta)``, ``p_m = u_a - cos(theta) u_m`` and
    ``p_a = u_m - cos(theta) u_a``: linear in the coefficients of ``F`` and ``G``.  With each
    component of ``F`` and ``G`` a polynomial of degree ``degree`` in its direction (a rotation
    ``w x u_m`` is of degree 1), the least-squares fit of the angle (in-sample, so optimistic)
    leaves what no such calibration explains.  Returns that spread, the white part (consecutive
    differences / sqrt 2), the spread over the stillest quarter of the samples (smallest
    accelerometer change) and the number of terms.
    """
    st = static_mask(a)
    um = m[st] / np.linalg.norm(m[st], axis=1, keepdims=True)
    ua = a[st] / np.linalg.norm(a[st], axis=1, keepdims=True)
    cos = np.clip(np.sum(um * ua, axis=1), -1.0, 1.0)
    theta, sin = np.arccos(cos), np.sqrt(1.0 - cos**2)
    n = len(theta)
    columns = [np.ones((n, 1))]
    for p, u in ((ua - cos[:, None] * um, um), (um - cos[:, None] * ua, ua)):
        columns.append((p[:, :, None] * orientation_features(u, degree)[:, None, :]).reshape(n, -1) / sin[:, None])
    x = np.hstack(columns)
    coef, *_ = np.linalg.lstsq(x, theta, rcond=None)
    pairs = st[:-1] & st[1:]
    white = np.std(np.diff(field_gravity_angles(m, a))[pairs]) / np.sqrt(2.0)
    change = np.linalg.norm(np.gradient(a, axis=0), axis=1)[st]
    still = change < np.quantile(change, 0.25)
    return float(np.degrees(np.std(theta - x @ coef))), float(white), float(np.std(field_gravity_angles(m, a)[st][still])), x.shape[1]


def check_floor():
    """The floor on simulated data: what calibration can fix must vanish, hand motion must stay."""
    print("\nCalibration floor check (simulated, 3000 samples, no hand motion unless said): angle std raw -> floor, deg")
    still = simulate_tumble(seed=1, n=3000, hard_iron_ut=0.0, soft_iron=0.0, misalign_deg=0.0, motion_g=0.0,
                            noise_ut=0.01, accel_noise_g=1e-4)
    moving = simulate_tumble(seed=1, n=3000, hard_iron_ut=0.0, soft_iron=0.0, misalign_deg=0.0, motion_g=0.05)
    cases = {"exact": (still.mag, still.accel),
             "3 deg misalignment": (Rotation.from_rotvec(np.radians([3.0, 0.0, 0.0])).apply(still.mag), still.accel),
             "2 uT offset": (still.mag + [2.0, 0.0, 1.0], still.accel),
             "5 % soft iron": (still.mag @ np.array([[1.05, 0.02, 0.0], [0.02, 0.97, 0.0], [0.0, 0.0, 1.0]]), still.accel),
             "exact, 0.05 g hand motion": (moving.mag, moving.accel)}
    for name, (m, a) in cases.items():
        st = static_mask(a)
        print(f"  {name:<28}{np.std(field_gravity_angles(m[st], a[st])):8.3f} ->{calibration_floor(m, a)[0]:7.3f}")


def drop_repeats(m, *others):
    keep = new_readings(m)
    return (m[keep],) + tuple(o[keep] for o in others)


def heading_error(m_h, a, sim):
    """RMS tilt-compensated heading error, deg, over undisturbed quasi-static samples (m_h in the housing frame)."""
    st = static_mask(a)
    st[sim.truth["outlier_rows"]] = False
    up, north = np.array([0.0, 0.0, 1.0]), world_field(sim.truth["dip_deg"])
    est = []
    for ai, mi in zip(a[st], m_h[st]):
        r, _ = Rotation.align_vectors([up, north], [ai / np.linalg.norm(ai), mi / np.linalg.norm(mi)],
                                      weights=[np.inf, 1.0])
        est.append(heading_pitch_roll(r)[0][0])
    err = np.mod(np.array(est) - sim.heading_deg[st] + 180.0, 360.0) - 180.0
    return float(np.sqrt(np.mean(err**2)))


def row(name, cells):
    print(f"{name:<34}" + "".join(f"{c:>14}" for c in cells))


def fmt(v, spec=".3f"):
    return "fail" if v is None or not np.isfinite(v) else format(v, spec)


def simulated(seeds=range(5)):
    print("\nSimulated tumbles (3000 samples, 2 % in disturbance bursts, 0.3 uT noise, 2 deg misalignment, 0.01 g hand motion)")
    row("metric (mean over seeds)", ["ours", "algebraic", "mag-cal"])
    acc = {k: [] for k in ("h", "s", "mis", "hdg")}
    for seed in seeds:
        sim = simulate_tumble(seed=seed, n=3000, outlier_fraction=0.02, motion_g=0.01)
        b = sim.truth["field_ut"]
        h_true, s_true = np.array(sim.truth["hard_iron"]), np.array(sim.truth["soft_iron"])
        s_true = s_true / np.cbrt(np.linalg.det(s_true))
        c_true = Rotation.from_matrix(sim.truth["mag_to_accel"])
        res = calibrate_tumble(sim.mag, sim.accel)
        fits = {"ours": (res.hard_iron, res.fit.soft_iron, res.misalignment.rotation),
                "algebraic": algebraic_fit(sim.mag), "mag-cal": magcal_fit(sim.mag)}
        for key in acc:
            acc[key].append([])
        for name, f in fits.items():
            if f is None:
                for key in acc:
                    acc[key][-1].append(np.nan)
                continue
            h, t = f[0], f[1]
            rot = f[2] if len(f) > 2 else None
            acc["h"][-1].append(100 * np.linalg.norm(h - h_true) / b)
            acc["s"][-1].append(np.linalg.norm(t - s_true))
            acc["mis"][-1].append(np.degrees((c_true.inv() * rot).magnitude()) if rot is not None else
                                  np.degrees(c_true.magnitude()))
            m = (sim.mag - h) @ t.T
            acc["hdg"][-1].append(heading_error(m if rot is None else rot.apply(m), sim.accel, sim))
    labels = {"h": "hard-iron error, % of |B|", "s": "soft-iron shape error (Frobenius)",
              "mis": "mag-accel rotation error, deg", "hdg": "heading error rms, deg"}
    for key, label in labels.items():
        row(label, [fmt(v) for v in np.nanmean(np.array(acc[key]), axis=0)])


def real(name, m, a, notes=True, floor=False):
    m, a = drop_repeats(m, a)
    res = calibrate_tumble(m, a)
    raw = metrics(m, a)
    if res.refused:
        print(f"\n{name}: {len(m)} samples after dropping repeats; refused (nothing written): {res.refused}")
        row("", ["raw"])
        row("|B| CV, %", [fmt(raw[0])])
        row("field-gravity angle std, deg", [fmt(raw[1])])
        return raw, None
    mc = res.calibrated(m)
    ours = metrics(mc if res.misalignment is None or res.misalignment.rotation is None
                   else res.misalignment.rotation.apply(mc), a)
    ours_no_rot = metrics(mc, a)
    peers = []
    for fit in (algebraic_fit(m), magcal_fit(m)):
        peers.append(None if fit is None else metrics((m - fit[0]) @ fit[1].T, a))
    print(f"\n{name}: {len(m)} samples after dropping repeats; chosen ellipsoid {res.ellipsoid}; "
          f"offset {np.linalg.norm(res.hard_iron) / res.fit.field_norm:.3f} of |B|")
    row("", ["raw", "ours", "ours no rot", "algebraic", "mag-cal"])
    row("|B| CV, %", [fmt(raw[0]), fmt(ours[0]), fmt(ours_no_rot[0])] + [fmt(p and p[0]) for p in peers])
    row("field-gravity angle std, deg", [fmt(raw[1]), fmt(ours[1]), fmt(ours_no_rot[1])] + [fmt(p and p[1]) for p in peers])
    if notes:
        for w in res.warnings:
            print(f"  warning: {w}")
    if floor:
        aligned = mc if res.misalignment is None or res.misalignment.rotation is None else res.misalignment.rotation.apply(mc)
        left, white, still, k = calibration_floor(aligned, a)
        print(f"  angle spread no further calibration can remove (first order, each direction turned by a cubic of "
              f"itself, {k} terms, in-sample): {left:.3f} deg; of it white (consecutive differences) {white:.3f} deg; "
              f"spread over the stillest quarter (least accelerometer change) {still:.3f} deg")
        box = np.ones(5) / 5.0
        smooth = [np.column_stack([np.convolve(v[:, j], box, mode="same") for j in range(3)]) for v in (aligned, a)]
        st = static_mask(a)
        print(f"  for comparison, noise reduction (not calibration): a 5-sample moving average of both sensors "
              f"gives {np.std(field_gravity_angles(smooth[0][st], smooth[1][st])):.3f} deg on the same samples")
    eig = np.linalg.eigvalsh(res.soft_iron)
    print(f"  soft iron eigenvalues {np.round(eig, 4)} (positive definite: {bool(np.all(eig > 0))}), det {np.linalg.det(res.soft_iron):.4f}")
    return raw, ours


def main():
    simulated()
    check_floor()
    ck = np.loadtxt(DATA / "ck-accmag" / "acc_mag_log.csv", delimiter=",", skiprows=1)
    real("CK acc_mag_log (real, raw)", ck[:, 3:6], ck[:, 0:3], floor=True)
    xio = np.loadtxt(DATA / "xio-fusion" / "sensor_data.csv", delimiter=",", skiprows=1)
    real("x-io Fusion sensor_data (real, never turned over)", xio[:, 7:10], xio[:, 4:7])
    for path in sorted((DATA / "broad").glob("*.mat")):
        d = loadmat(path, squeeze_me=True)
        move = d["movement"].astype(bool)
        real(f"BROAD {path.stem} (motion phase, every 4th row)", d["imu_mag"][move][::4], d["imu_acc"][move][::4],
             notes=False)


if __name__ == "__main__":
    main()
