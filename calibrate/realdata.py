"""The residual loop on real data with a ground truth (BROAD trials): base model, residual, effects.

``python -m calibrate.realdata [DATA_DIR] [--out CAL.json]`` prints the before/after table.

With the optical reference ``R_NWU<-H`` of every sample, the field the magnetometer reports can be
put into the world frame, ``h_i = R_i m_i``, where it must be constant.  The residual of a model is
that field's departure from a constant, in the three figures that matter for a compass (each after a
0.25 s moving average in the world frame, which removes sensor noise but no model error):

- *azimuth RMS*: RMS angle of ``h``'s horizontal part from magnetic north (the heading error of an
  ideal compass using that field), degrees;
- *|B| spread* and *dip spread*: standard deviations of ``|h|`` (uT) and of its dip (degrees).

The loop starts from the base model (the readings as delivered) and tries, in turn, effects the base
model lacks; each is fitted on the *training* trials only and kept when it lowers the training
residual (sum of the three figures in their units) by more than ``MIN_GAIN``.  The table reports every
trial, the training ones marked: only the others are a score.  Nothing is tuned per trial.

Effects (names in the SPEC section 4 style):

``misalignment``
    a rotation between magnetometer and body (accelerometer / optical) frames, 3 parameters.
``soft_iron``
    ``m' = S (m - b)``: symmetric ``S`` with unit determinant and a hard-iron ``b``, 8 parameters.
``mag_latency``
    the magnetometer sample lags the reference by ``k`` samples (integer, searched 0..12).
``hard_iron_step``
    a housing-fixed offset appearing and disappearing in time (a magnet attached): the causal tracker
    :func:`compass.hard_iron.track_hard_iron`, which needs no truth and has no fitted parameters.
    With the truth, the step is also located by change-point detection on the body-frame residual
    ``m - R^T h_0``, to check the tracker's timing.
``field_gradient``
    the field varies across the room linearly with the position ``opt_pos`` (9 parameters).  The
    runtime does not know its position, so this one is a diagnosis only: it is reported, never
    written into the calibration.

Data: BROAD (Laidig, Caruso, Cereatti, Seel, Data 6(7):72, 2021, doi:10.3390/data6070072), CC BY 4.0.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.ndimage import uniform_filter1d
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from compass.calibration import header, save
from compass.hard_iron import track_hard_iron
from compass.io.broad import BroadTrial, enu_to_nwu, read_broad
from compass.io.progress import working

__all__ = ["TRAIN", "MIN_GAIN", "LATENCIES", "Residual", "StaticCorrection", "world_residual", "fit_static",
           "change_points", "loop_units", "run_loop"]

TRAIN = ("01", "02")
"""Trial number prefixes the static effects are fitted on (undisturbed; the rest is scored)."""
MIN_GAIN = 0.05
"""Smallest relative drop of the training residual that keeps an effect."""
LATENCIES = tuple(range(0, 13, 2))
"""Magnetometer latencies tried, samples."""
SMOOTH_S = 0.25
_SUBSAMPLE = 10


@dataclass(frozen=True)
class Residual:
    """The world-frame field's departure from a constant (see the module docstring)."""

    azimuth_rms_deg: float
    norm_std_ut: float
    dip_std_deg: float

    @property
    def total(self) -> float:
        return self.azimuth_rms_deg + self.norm_std_ut + self.dip_std_deg


@dataclass(frozen=True)
class StaticCorrection:
    """Time-invariant corrections in the magnetometer frame: ``m' = C S (m_{t+k} - b)``."""

    rotation: Rotation
    soft_iron: np.ndarray
    hard_iron_ut: np.ndarray
    latency_samples: int

    def apply(self, mag_ut: np.ndarray) -> np.ndarray:
        """Corrected field in the body frame, uT, shape (n, 3) (the last ``k`` samples repeat)."""
        m = np.asarray(mag_ut, dtype=float)
        if self.latency_samples:
            m = np.concatenate([m[self.latency_samples:], np.repeat(m[-1:], self.latency_samples, axis=0)])
        return self.rotation.apply((m - self.hard_iron_ut) @ self.soft_iron.T)


BASE = StaticCorrection(Rotation.identity(), np.eye(3), np.zeros(3), 0)


def world_residual(trial: BroadTrial, field_h_ut: np.ndarray, position_gradient=None) -> Residual:
    """Residual of a body-frame field against a constant world field, movement phase, truth rows.

    Parameters
    ----------
    trial : BroadTrial
    field_h_ut : ndarray, shape (n, 3)
        Model's field in the body frame, uT.
    position_gradient : ndarray, shape (3, 3), optional
        ``dh/dpos`` (uT/m, NWU): subtracted from the world field as ``G (pos - mean pos)``.
    """
    h = _world_field(trial, field_h_ut, position_gradient)
    horizontal = np.hypot(h[:, 0], h[:, 1])
    azimuth = np.degrees(np.arctan2(h[:, 1], h[:, 0]))
    dip = np.degrees(np.arctan2(-h[:, 2], horizontal))
    return Residual(float(np.sqrt(np.mean(azimuth**2))), float(np.std(np.linalg.norm(h, axis=1))), float(np.std(dip)))


def _world_field(trial, field_h_ut, position_gradient=None) -> np.ndarray:
    """Smoothed world-frame field (NWU, uT) on the scored rows."""
    valid = trial.ref_valid
    h = np.full((len(trial), 3), np.nan)
    h[valid] = trial.reference("nwu").apply(np.asarray(field_h_ut)[valid])
    keep = valid & trial.movement
    if position_gradient is not None:
        pos = trial.ref_pos_m - np.nanmean(trial.ref_pos_m[keep], axis=0)
        h = h - pos @ np.asarray(position_gradient).T
    width = max(int(SMOOTH_S * trial.rate_hz), 1)
    filled = np.where(np.isfinite(h), h, 0.0)
    count = uniform_filter1d(np.isfinite(h[:, 0]).astype(float), width)
    smooth = uniform_filter1d(filled, width, axis=0) / np.maximum(count, 1e-9)[:, None]
    keep &= np.all(np.isfinite(smooth), axis=1) & (count > 0.5)
    return smooth[keep]


def _truth(trial, idx) -> Rotation:
    """``R_NWU<-H`` at rows ``idx`` (rows with a reference)."""
    return enu_to_nwu(Rotation.from_quat(trial.ref_quat_enu[idx], scalar_first=True))


def _scored_rows(trial, latency: int = 0) -> np.ndarray:
    idx = np.flatnonzero(trial.ref_valid & trial.movement)[::_SUBSAMPLE]
    return idx[idx + latency < len(trial)]


def fit_static(trials, effects: tuple[str, ...], latency: int = 0) -> StaticCorrection:
    """Fit the named static effects (``misalignment``, ``soft_iron``) on trials with a truth.

    Least squares of ``R_i C S (m_{i+k} - b) - h_0`` over the scored samples (every tenth), robust
    (soft-L1, 2 uT), with the world field ``h_0 = (north, 0, down)`` free; ``det S = 1`` keeps the
    field's scale from trading off against ``S``.
    """
    rows = [_scored_rows(t, latency) for t in trials]
    rs = [_truth(t, idx) for t, idx in zip(trials, rows)]
    ms = [t.mag_ut[idx + latency] for t, idx in zip(trials, rows)]

    def unpack(p):
        c = Rotation.from_rotvec(p[:3]) if "misalignment" in effects else Rotation.identity()
        s, b = np.eye(3), np.zeros(3)
        if "soft_iron" in effects:
            u = p[5:11]
            s = np.eye(3) + np.array([[u[0], u[3], u[4]], [u[3], u[1], u[5]], [u[4], u[5], u[2]]])
            s = s / np.cbrt(np.linalg.det(s))
            b = p[11:14]
        return c, s, b, np.array([p[3], 0.0, p[4]])

    def resid(p):
        c, s, b, h0 = unpack(p)
        return np.concatenate([(r.apply(c.apply((m - b) @ s.T)) - h0).ravel() for r, m in zip(rs, ms)])

    p0 = np.r_[np.zeros(3), 15.0, -40.0, np.zeros(9)]
    p = least_squares(resid, p0, loss="soft_l1", f_scale=2.0).x
    c, s, b, _ = unpack(p)
    return StaticCorrection(c, s, b, latency)


def fit_gradient(trials, correction: StaticCorrection) -> np.ndarray:
    """World-field gradient ``dh/dpos`` (uT/m, NWU, 3x3) by least squares on the training trials."""
    rows, targets = [], []
    for t in trials:
        idx = _scored_rows(t)
        idx = idx[np.all(np.isfinite(t.ref_pos_m[idx]), axis=1)]
        pos = t.ref_pos_m[idx] - t.ref_pos_m[idx].mean(axis=0)
        rows.append(np.column_stack([pos, np.ones(len(pos))]))
        targets.append(_truth(t, idx).apply(correction.apply(t.mag_ut)[idx]))
    coef, *_ = np.linalg.lstsq(np.vstack(rows), np.vstack(targets), rcond=None)
    return coef[:3].T


def change_points(trial: BroadTrial, threshold_ut: float = 5.0, min_s: float = 5.0) -> list[tuple[float, float]]:
    """Intervals (start_s, end_s) where a housing-fixed offset is present, located with the truth.

    The body-frame residual ``m - R^T h_0`` (``h_0`` the world field over the first half of the
    initial rest) is smoothed over 1 s; intervals where its norm exceeds ``threshold_ut`` for at
    least ``min_s`` are returned (a change-point rule on the earth-frame field).
    """
    valid = trial.ref_valid
    r = trial.reference("nwu")
    n_rest = int(np.argmax(trial.movement))
    h_world = r.apply(trial.mag_ut[valid])
    h0 = np.median(h_world[: max(n_rest // 2, 1)], axis=0)
    off = np.full((len(trial), 3), np.nan)
    off[valid] = trial.mag_ut[valid] - r.apply(h0, inverse=True)
    width = int(trial.rate_hz)
    filled = np.where(np.isfinite(off), off, 0.0)
    count = uniform_filter1d(np.isfinite(off[:, 0]).astype(float), width)
    smooth = uniform_filter1d(filled, width, axis=0) / np.maximum(count, 1e-9)[:, None]
    above = (np.linalg.norm(smooth, axis=1) > threshold_ut) & (count > 0.5)
    edges = np.flatnonzero(np.diff(np.r_[0, above.astype(int), 0]))
    return [(s / trial.rate_hz, e / trial.rate_hz) for s, e in zip(edges[::2], edges[1::2])
            if (e - s) / trial.rate_hz >= min_s]


def loop_units(n_trials: int) -> int:
    """The units of work :func:`run_loop` counts on ``n_trials`` trials: the base, two static effects, each
    latency, the gradient, each trial's row."""
    return 4 + len(LATENCIES) + n_trials


def run_loop(trials: list[BroadTrial], *, tally=None) -> tuple[list[str], StaticCorrection, dict]:
    """The loop: returns (table lines, final static correction, summary for the calibration file).

    ``tally`` (:class:`compass.io.progress.Tally`, optional) is advanced ``loop_units(len(trials))`` times.
    """
    advance = (lambda: None) if tally is None else tally.advance
    train = [t for t in trials if t.name[:2] in TRAIN]
    if not train:
        raise ValueError(f"no training trial (numbers {', '.join(TRAIN)}) among the trials")

    def train_total(corr, gradient=None):
        return float(np.mean([world_residual(t, corr.apply(t.mag_ut), gradient).total for t in train]))

    steps = [("base", BASE, train_total(BASE), "")]
    advance()
    current, kept = BASE, []
    for effect in ("misalignment", "soft_iron", "mag_latency"):
        if effect == "mag_latency":
            candidates, scores = [], []
            for k in LATENCIES:
                candidates.append(fit_static(train, tuple(kept), latency=k))
                scores.append(train_total(candidates[-1]))
                advance()
            candidate, score = candidates[int(np.argmin(scores))], min(scores)
            note = f"k = {candidate.latency_samples} samples"
        else:
            candidate = fit_static(train, tuple(kept + [effect]), latency=current.latency_samples)
            score = train_total(candidate)
            advance()
            note = ""
        gain = 1.0 - score / steps[-1][2]
        keep = gain > MIN_GAIN
        steps.append((effect, candidate, score, f"{note} train residual {steps[-1][2]:.2f} -> {score:.2f} "
                                              f"({100 * gain:+.0f} %){'' if keep else ': not kept'}"))
        if keep:
            current = candidate
            if effect != "mag_latency":
                kept.append(effect)
    gradient = fit_gradient(train, current)
    advance()

    lines = ["world-frame field residual per trial (movement phase, truth orientation, 0.25 s average): "
             "azimuth RMS deg / |B| std uT / dip std deg",
             "* = training trial (fitted on it, not a score)"]
    for name, _, score, note in steps[1:]:
        lines.append(f"  effect {name}: {note}")
    header = f"{'trial':44s} {'base':>17s} {'+static':>17s} {'+hard iron':>17s} {'+gradient*':>17s}  steps (truth / tracker)"
    lines.append(header)
    rows = {}
    for t in trials:
        base = world_residual(t, t.mag_ut)
        static = current.apply(t.mag_ut)
        dip = _initial_dip(t, static)
        track = track_hard_iron(static, t.accel_m_s2, t.rate_hz, dip_deg=dip)
        fixed = track.corrected(static)
        cells = [base, world_residual(t, static), world_residual(t, fixed), world_residual(t, fixed, gradient)]
        truth = ", ".join(f"{a:.0f}-{b:.0f}" for a, b in change_points(t)) or "-"
        tracker = ", ".join(f"{s:.0f}" for s in track.step_t_s) or "-"
        mark = "*" if t in train else " "
        lines.append(f"{mark}{t.name:43s} " + " ".join(f"{c.azimuth_rms_deg:5.2f}/{c.norm_std_ut:4.2f}/{c.dip_std_deg:4.2f}"
                                                        for c in cells) + f"  {truth} / {tracker}")
        rows[t.name] = cells
        advance()
    for group in ("undisturbed", "disturbed"):
        members = [rows[t.name] for t in trials if t not in train and f"_{group}" in "_" + t.name.split("_", 1)[1]]
        if members:
            mean = np.mean([[c.azimuth_rms_deg for c in r] for r in members], axis=0)
            lines.append(f" mean azimuth RMS, scored {group} ({len(members)})".ljust(45)
                         + " ".join(f"{v:17.2f}" for v in mean))
    lines.append("  (+gradient: field_gradient fitted on the training trials vs opt_pos; diagnosis only, the runtime "
                 "does not know its position)")
    summary = {"effects": kept + (["mag_latency"] if current.latency_samples else []),
               "gradient_ut_per_m": gradient.tolist(), "train": list(TRAIN)}
    return lines, current, summary


def _initial_dip(trial, field_h_ut) -> float:
    from compass.evaluation import initial_field

    return initial_field(field_h_ut, trial.accel_m_s2, ~trial.movement)[1]


def calibration_json(correction: StaticCorrection, trials, summary: dict) -> dict:
    """A tumble-form calibration file (SPEC section 2) of the static correction.

    Latency is not part of the file format and is reported under ``realdata`` only.
    """
    from compass.evaluation import initial_field

    train = [t for t in trials if t.name[:2] in TRAIN]
    refs = [initial_field(correction.apply(t.mag_ut), t.accel_m_s2, ~t.movement) for t in train]
    field, dip, noise = np.mean(refs, axis=0)
    return header("tumble") | {"hard_iron": correction.hard_iron_ut.tolist(),
            "soft_iron": correction.soft_iron.tolist(), "field_norm": float(field),
            "mag_to_accel": correction.rotation.as_matrix().tolist(), "field_ut": float(field), "dip_deg": float(dip),
            "noise_floor": [float(noise)] * 3, "channel_columns": ["mx", "my", "mz"],
            "effects": [{"name": e, "parameters": {}} for e in summary["effects"]],
            "realdata": summary | {"latency_samples": correction.latency_samples,
                                   "source": "BROAD (Laidig et al., Data 6(7):72, 2021), CC BY 4.0"}}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description="The residual loop on BROAD trials with ground truth.")
    parser.add_argument("data", nargs="?", default=str(Path(__file__).resolve().parents[2] / "shared" / "data" / "broad"))
    parser.add_argument("--out", help="write the fitted static correction as a tumble calibration file")
    args = parser.parse_args(argv)
    files = sorted(Path(args.data).glob("*.mat"))
    if not files:
        print(f"no BROAD trials in {args.data}")
        return 2
    # reading each trial, then the loop's units
    units = len(files) + loop_units(len(files))
    with working(f"the residual loop on {len(files)} BROAD trials", total=units) as tally:
        trials = []
        for f in files:
            trials.append(read_broad(f))
            tally.advance()
        lines, correction, summary = run_loop(trials, tally=tally)
    print("\n".join(lines))
    if args.out:
        save(args.out, calibration_json(correction, trials, summary), force=True)
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
