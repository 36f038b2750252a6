"""BROAD trials through peer filters and the toolkit's pipeline, side by side, with BROAD's metric.

Run: ``python tools/bench_broad.py [DATA_DIR] [--quick] [--trials 01,32] [--cal CAL.json]`` (default data:
``../shared/data/broad``; ``--quick``: five trials, one per kind of motion).  Issue 22: ``--peers vqf`` runs only the
named peers (Madgwick's pure-Python loop is the slowest part of a run); ``--candidates A,B`` runs only those
candidates (and the turn variants, printed per trial, never chosen); the simulated boards (``compass.sim.motion``, a
BROAD-like and a low-cost IMU) follow the BROAD tables (``--sim-seeds N``, 0 for none; ``--sim-first-seed K``: seeds K
to K + N - 1, to judge a change on seeds it was not developed on; ``--sim-only``; with ``--candidates``, the named
candidates; ``--sim-mag-hz F``: their magnetometer converts at F Hz, each reading held until the next); the candidate
``mag_latency_s fitted`` takes the latency from a tumble calibration file of another recording (BROAD:
:data:`CAL_TRIALS`' motion phases, the trial scored never its own; a simulated board: its own fast rotation at another
seed), never from the truth; ``--latency-check`` runs the compensation on motions whose only error is the latency;
``--diagnose`` prints the inclination by turn rate of the filter, of its inertial low-pass's direction and of VQF, and
the one start's parts switched back; ``--bands`` splits the tilt error by time scale (the filter, the filter with
every field reading refused, VQF, and the motion the inertial low-pass leaves, truth-based) per trial and group
(``--write-docs``: its table in docs/benchmarks.md); ``--leak`` prints the leak of the inertial low-passes (ours, with
a 1 s Kalman pole, VQF's) and its correlation times, truth-based.  Peers are benchmark extras (``pip install -e
'.[bench]'``), never runtime dependencies; a peer that is not installed is reported and skipped.

The protocol (issue 13): every design choice of the toolkit's pipeline is a *candidate* (the
defaults; each mechanism removed, the ablation; each physical constant at half and twice its
default, the two correlation times on a grid; the noise measured on the trial's own initial rest).  Leave one trial out: the candidate
with the best score on the other trials (mean of log heading RMS plus mean of log inclination RMS:
every trial counts by its relative change) is chosen and scored on the held-out trial, which it
never saw.  The table prints that held-out score ("ours LOO", with the choice) beside the peers and
the defaults; the ablation table prints each candidate on all trials; the timing section prints
microseconds per sample of the toolkit's filter beside VQF's and imufusion's, same process.

Data: BROAD, D. Laidig, M. Caruso, A. Cereatti, T. Seel, "BROAD - A Benchmark for Robust Inertial
Orientation Estimation", Data 6(7):72, 2021, https://doi.org/10.3390/data6070072 (CC BY 4.0).

Every method gets the same raw arrays (gyro rad/s, accelerometer m/s^2, magnetometer uT) and returns
``R_ENU<-body`` (scalar first).  Frames: VQF's ``quat9D`` is body->ENU with magnetic north already;
x-io Fusion (imufusion 1.3) is run with its NWU convention and converted (``Rz(+90 deg)``); ahrs'
Madgwick works in NWU too (gravity up, field's north along +X) and is converted the same way; the
toolkit's filter is NWU (SPEC section 1).  Each conversion is checked first on a synthetic still
sensor with a known orientation, and the bench stops if any is off by more than 1 degree.

Recommended settings: VQF and offline VQF defaults (their authors'); Fusion the settings of its
README example (gain 0.5, gyroscope range 2000 deg/s, acceleration and magnetic rejection 10 deg,
rejection timeout 5 s, gyro offset correction on); Madgwick the ahrs default MARG gain.  The toolkit:
``FilterConfig`` defaults, |B|, dip and magnetometer noise from the trial's initial rest; "no gate"
widens every gate tolerance so the field is always used; "hard iron" adds the causal hard-iron
step tracker (:mod:`compass.hard_iron`); "cal" applies a calibration file (``--cal``, e.g. from
``python -m calibrate.realdata``), fitted on other trials.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

from compass.evaluation import METRIC, error_series, initial_field, rest_noise  # noqa: E402
from compass.io.broad import nwu_to_enu, read_broad  # noqa: E402
from compass.calibration import load as load_calibration
from _doc_table import markdown_table, parse_args, publish  # noqa: E402

GRAVITY = 9.81
QUICK_TRIALS = ("01", "06", "15", "24", "32")  # slow and fast rotation, translation, tapping, a magnet


def vqf_online(trial):
    from vqf import VQF

    out = VQF(1.0 / trial.rate_hz).updateBatch(*_contiguous(trial))
    return out["quat9D"]


def vqf_offline(trial):
    from vqf import offlineVQF

    return offlineVQF(*_contiguous(trial), 1.0 / trial.rate_hz)["quat9D"]


def fusion(trial):
    import imufusion

    rate = trial.rate_hz
    ahrs = imufusion.Ahrs()
    # imufusion 1.3 ignores convention= in the constructor: set it as an attribute, and convert from
    # NWU whatever it says (checked on the synthetic case)
    settings = imufusion.AhrsSettings(sample_rate=rate, gain=0.5, gyroscope_range=2000.0, acceleration_rejection=10.0,
                                      magnetic_rejection=10.0, rejection_timeout=int(5 * rate))
    settings.convention = imufusion.CONVENTION_NWU
    ahrs.set_settings(settings)
    bias = imufusion.Bias()
    bias.set_settings(imufusion.BiasSettings(sample_rate=rate))
    gyro_deg = np.degrees(trial.gyro_rad_s)
    acc_g = trial.accel_m_s2 / GRAVITY
    q = np.empty((len(trial), 4))
    for i in range(len(trial)):
        ahrs.update(bias.update(gyro_deg[i]), acc_g[i], trial.mag_ut[i])
        q[i] = ahrs.get_quaternion()  # w, x, y, z
    return nwu_to_enu(Rotation.from_quat(q, scalar_first=True)).as_quat(scalar_first=True)


def madgwick(trial):
    from ahrs.filters import Madgwick

    q = Madgwick(gyr=trial.gyro_rad_s, acc=trial.accel_m_s2, mag=trial.mag_ut, frequency=trial.rate_hz).Q
    return nwu_to_enu(Rotation.from_quat(q, scalar_first=True)).as_quat(scalar_first=True)


# ---------------------------------------------------------------- the toolkit's candidates

NO_GATE = {"field_tolerance": 1e6, "dip_tolerance_deg": 1e6, "heading_tolerance_deg": 1e6, "gate_timeout_s": 1e9}

CANDIDATES = {  # name: (FilterConfig changes, hard-iron tracker on, noise from the initial rest)
    "defaults": ({}, True, False),
    "- hard-iron tracker": ({}, False, False),
    "- gate": (NO_GATE, True, False),
    "- gate reference following": ({"field_reference_tau_s": 1e9}, True, False),
    "- dip-wander field error": ({"field_error_from_dip": False}, True, False),
    "- rest bias": ({"rest_bias_estimation": False}, True, False),
    "rest unconfirmed (before)": ({"rest_confirm_s": 0.0}, True, False),  # issue 22: the rest's tail taken for bias
    # issue 22: the start's rest counted from the detector's 1.5 s; the field's heading row held off the start's bias
    "start rest from 1.5 s (before)": ({"start_rest_bias": False}, True, False),
    "start heading row held": ({"start_field_bias_hold": True}, True, False),
    "start heading row held only": ({"start_rest_bias": False, "start_field_bias_hold": True}, True, False),
    "- motion-adaptive accel": ({"motion_adaptive_accel": False}, True, False),
    "- inertial low-pass": ({"accel_time_constant_s": 0.01}, True, False),
    "- gyro scale-error noise": ({"gyro_scale_error": 1e-9}, True, False),
    "second-order inertial low-pass": ({"accel_lowpass_order": 2}, True, False),  # issue 22's turn analysis
    "field update: no tilt": ({"field_update": "no-tilt"}, True, False),  # issue 22: the field never moves the tilt
    "field update: heading only": ({"field_update": "heading"}, True, False),  # ... nor the horizontal gyro bias
    "field update: heading and tilt model": ({"field_update": "heading-tilt"}, True, False),  # ... tilt in its model
    "motion residual in band": ({"residual_in_band": True}, True, False),  # issue 22: vibration and taps
    "noise from rest": ({}, True, True),
    "mag_latency_s 0.014": ({"mag_latency_s": 0.014}, True, False),  # calibrate.realdata's loop, on 01 and 02
    "mag_latency_s fitted": ({"mag_latency_s": "fitted"}, True, False),  # issue 22: another recording's tumble file
    "gyro_matrix fitted": ({"gyro_matrix": "fitted"}, True, False),  # issue 22: the gyro's scale and axes, the same
    "accel_time_constant_s 1": ({"accel_time_constant_s": 1.0}, True, False),
    "accel_time_constant_s 4": ({"accel_time_constant_s": 4.0}, True, False),
    "accel_time_constant_s 3 (VQF's)": ({"accel_time_constant_s": 3.0}, True, False),  # the default until issue 13
    "mag_heading_sigma_deg 0.5": ({"mag_heading_sigma_deg": 0.5}, True, False),
    "mag_heading_sigma_deg 2": ({"mag_heading_sigma_deg": 2.0}, True, False),  # the default until issue 13
} | {  # the two correlation times together: the accelerometer residual's and the field error's
    f"motion {m:g} s, field error {e:g} s": ({"motion_time_s": m, "field_error_time_s": e}, True, False)
    for m in (0.5, 1.0, 2.0) for e in (1.0, 2.0, 4.0) if (m, e) != (1.0, 1.0)
}

TURN_VARIANTS = {  # issue 22's turn analysis, run only when named in --candidates (not leave-one-out candidates)
    "Butterworth 3 s": ({"accel_lowpass_order": 2, "accel_time_constant_s": 3.0}, True, False),
    "Butterworth 3 s and motion 1 s": ({"accel_lowpass_order": 2, "accel_time_constant_s": 3.0, "motion_time_s": 1.0},
                                    True, False),
    "gyro_scale_error 0.01": ({"gyro_scale_error": 0.01}, True, False),
    "lever arm": ({"lever_arm": True}, True, False),  # a hand-held turn's lever arm out of the low-pass
}


def ours_config(trial, field, changes=None, from_rest=False):
    """FilterConfig from the trial's initial rest (|B|, dip, magnetometer noise; with ``from_rest``
    the gyro and accelerometer noise too), with ``changes``."""
    from compass.filter import FilterConfig

    field_ut, dip_deg, noise_ut = initial_field(field, trial.accel_m_s2, ~trial.movement)
    config = FilterConfig(field_norm=field_ut, dip_deg=dip_deg, mag_noise=noise_ut)
    if from_rest:
        noise = rest_noise(trial.gyro_rad_s, trial.accel_m_s2, field, ~trial.movement, trial.rate_hz)
        config = replace(config, gyro_noise=noise.gyro_noise, accel_noise=noise.accel_noise)
    return replace(config, **(changes or {}))


def ours(changes=None, hard_iron=True, from_rest=False, model=None):
    """The toolkit's causal pipeline: calibration (optional), hard-iron tracker, the live filter."""

    def run(trial):
        track = ours_track(trial, changes, hard_iron, from_rest, model)
        return nwu_to_enu(Rotation.from_quat(track.quat)).as_quat(scalar_first=True)

    return run


def ours_track(trial, changes=None, hard_iron=True, from_rest=False, model=None):
    """:func:`ours`' pipeline on one trial: its :class:`compass.filter.FilterTrack` (the gate's answers too)."""
    from compass.filter import run_filter
    from compass.hard_iron import track_hard_iron

    field = trial.mag_ut if model is None else model.field(trial.mag_ut)[0]
    fitted = {k: _fitted(trial)[k] for k, v in (changes or {}).items() if v == "fitted"}
    config = ours_config(trial, field, (changes or {}) | fitted, from_rest)
    if hard_iron:
        field = track_hard_iron(field, trial.accel_m_s2, trial.rate_hz, dip_deg=config.dip_deg).corrected(field)
    return run_filter(trial.t_s, trial.accel_m_s2, trial.gyro_rad_s, field, config)


def loo_choice(results, trial, candidates):
    """The candidate with the best score on every trial but ``trial`` (mean log heading + mean log inclination)."""
    others = [t for t in results if t != trial]  # trial None: all of them
    if not others:
        return "defaults"
    return min(candidates, key=lambda c: (np.mean([np.log(results[t][c][0]) for t in others])
                                          + np.mean([np.log(results[t][c][1]) for t in others])))


# ---------------------------------------------------------------- the latency from a calibration recording

CAL_TRIALS = ("01", "02")
"""BROAD trials whose motion phase is a tumble recording for the latency: a trial is scored with the first
one that is not itself (the latency fitted on another trial: leave one out)."""


def file_values(t_s, gyro, accel, mag, keep) -> dict:
    """The magnetometer latency and the gyro matrix a tumble calibration of the rows ``keep`` writes, as the runtime
    reads them: ``{"mag_latency_s": s, "gyro_matrix": 3 x 3 tuple or None, "gyro_scale_error": the filter's, as read}``.

    ``compass calibrate``'s path with a gyro (the present fit, the gyro-aided one where it falls back, and the
    gyro-aided one's latency and gyro matrix either way), its file, and :func:`compass.calibration.from_dict`'s
    ``model.mag_latency_s`` (0 unless the magnetometer is late beyond 3 sigma) and ``model.gyro_matrix`` (the
    entries seen): the truth is never read.
    """
    import warnings

    from calibrate.tumble import calibrate_tumble
    from calibrate.tumble.gyro import with_gyro
    from compass.calibration import from_dict
    from compass.filter import fitted_scale_error
    from compass.io.tumble import gyro_turns

    turns = gyro_turns(t_s, gyro, keep)
    mag, acc, t = mag[keep], accel[keep], t_s[keep]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = with_gyro(calibrate_tumble(mag, acc, t_s=t), mag, acc, turns, t)
    doc = res.to_json()
    model = from_dict(doc).model
    g = model.gyro_matrix
    fitted = doc.get("tumble", {}).get("gyro", {})  # what the fit wrote, for the words only
    accel = model.accel_correction
    return {"mag_latency_s": model.mag_latency_s, "gyro_matrix": None if g is None else tuple(map(tuple, g)),
            "gyro_scale_error": fitted_scale_error(model, False),
            "accel_correction": None if accel is None else (tuple(map(tuple, accel[0])), tuple(accel[1]), accel[2]),
            "fitted": (fitted.get("gyro_matrix"), fitted.get("gyro_matrix_sigma")),
            "accel_from_gyro": tuple((doc.get("accelerometer") or {}).get("from_gyro", ()))}


def _values_words(values: dict) -> str:
    g = values["gyro_matrix"]
    fitted, sigma = values.get("fitted", (None, None))
    sigma = None if sigma is None else 100 * np.array([[np.inf if v is None else v for v in r] for r in sigma])
    return (f"latency {1e3 * values['mag_latency_s']:.2f} ms, gyro matrix "
            + ("none seen" if g is None else "diag " + ", ".join(f"{100 * (g[i][i] - 1):+.2f}" for i in range(3))
               + f" %, off-diagonal up to {100 * np.max(np.abs(np.array(g) - np.diag(np.diag(g)))):.2f} %")
            + ("" if sigma is None else f" (fitted sigma diag {', '.join(f'{v:.2f}' for v in np.diag(sigma))} %, "
               f"off-diagonal up to {np.max(sigma[~np.eye(3, dtype=bool)]):.2f} %)"))


def broad_fitted(data: Path) -> dict[str, dict]:
    """``{trial number: file values}`` (:func:`file_values`) of :data:`CAL_TRIALS` (each motion phase, every 4th row,
    the gyro integrated over every row, as ``tools/bench_gyro_tumble.py``)."""
    out = {}
    for number in CAL_TRIALS:
        path = next(iter(sorted(data.glob(f"{number}_*.mat"))), None)
        if path is None:
            continue
        t = read_broad(path)
        keep = np.zeros(len(t), bool)
        keep[np.flatnonzero(t.movement)[::4]] = True
        out[number] = file_values(t.t_s, t.gyro_rad_s, t.accel_m_s2, t.mag_ut, keep)
        print(f"  from {t.name}'s tumble file: {_values_words(out[number])}", flush=True)
    return out


NONE_FITTED = {"mag_latency_s": 0.0, "gyro_matrix": None, "gyro_scale_error": 0.005, "accel_correction": None}

BROAD_FITTED: dict[str, dict] = {}
"""Each BROAD trial's held-out file values (:func:`held_out`), by name; a simulated trial carries its own."""


def _fitted(trial) -> dict:
    return trial.fitted if isinstance(trial, _Simulated) else BROAD_FITTED[trial.name]


def held_out(name: str, fitted: dict[str, dict]) -> dict:
    """The values fitted on the first calibration trial that is not ``name`` (none when there is none)."""
    return next((v for k, v in fitted.items() if not name.startswith(k)), NONE_FITTED)


def latency_check(seeds) -> None:
    """Heading RMS on simulated motions whose only sensor error is a 20 ms late magnetometer (and white noise),
    the latency compensated or not, beside the same motions on time: the compensation alone, isolated from the
    other errors of a board (the hard-iron tracker off: there is no iron)."""
    from compass.sim.motion import KINDS, SensorErrors, simulate_motion

    print(f"\nthe latency alone (compass.sim.motion, 60 s, seeds {list(seeds)}): heading RMS, deg")
    print(f"{'kind':18s} {'on time':>9s} {'20 ms late':>11s} {'compensated':>12s}")
    for kind in KINDS:
        cells = []
        for late_s, tau in ((0.0, 0.0), (0.02, 0.0), (0.02, 0.02)):
            rms = []
            for seed in seeds:
                trial = _Simulated(simulate_motion(kind, seed=seed, errors=SensorErrors(mag_latency_s=late_s)), kind)
                e = error_series(ours({"mag_latency_s": tau}, hard_iron=False)(trial), trial.ref_quat_enu,
                                 trial.movement, trial.rate_hz)
                rms.append(e.heading_rms_deg)
            cells.append(np.mean(rms))
        print(f"{kind:18s} {cells[0]:9.3f} {cells[1]:11.3f} {cells[2]:12.3f}", flush=True)


# ---------------------------------------------------------------- simulated boards

FITTED_CANDIDATES = ("mag_latency_s fitted", "gyro_matrix fitted")
"""The candidates that take a value from another recording's tumble file."""

SIM_CANDIDATES = ("defaults", "second-order inertial low-pass", "mag_latency_s fitted",
                  "field update: heading and tilt model")


class _Simulated:
    """A :func:`compass.sim.motion.simulate_motion` trial duck-typed as a BroadTrial (ENU reference)."""

    def __init__(self, rec, name):
        from compass.io.broad import nwu_to_enu

        self.name, self.rate_hz = name, 1.0 / (rec.t_s[1] - rec.t_s[0])
        self.t_s, self.gyro_rad_s, self.accel_m_s2, self.mag_ut = rec.t_s, rec.gyro_rad_s, rec.accel_m_s2, rec.mag_ut
        self.movement = rec.moving
        self.ref_quat_enu = nwu_to_enu(rec.rotation).as_quat(scalar_first=True)

    def __len__(self):
        return len(self.t_s)


def board_errors(board: str, seed: int):
    """The simulated IMU's errors: ``"broad-like"`` (0.5 % gyro scale, small biases), ``"low-cost"``
    (gyro scale 1-2 %, bias up to 1 deg/s, accelerometer scale 2 % and offset 0.15 m/s^2, magnetometer
    20 ms late) or ``"bad-accel"`` (the low-cost board with an uncalibrated accelerometer: offsets 1-2 m/s^2 and
    scales 5-10 % of either sign, as the real board that read 0.77-1.30 g at rest), drawn per seed; nothing here
    was chosen for a filter change."""
    from compass.sim.motion import SensorErrors

    rng = np.random.default_rng(1000 + seed)
    sign = rng.choice([-1.0, 1.0], 3)
    if board == "broad-like":
        return SensorErrors(gyro_bias_rad_s=tuple(rng.normal(0.0, np.radians(0.3), 3)),
                            gyro_scale=tuple(sign * 0.005), mag_latency_s=0.0)
    low_cost = SensorErrors(gyro_bias_rad_s=tuple(rng.normal(0.0, np.radians(0.5), 3)),
                            gyro_scale=tuple(sign * rng.uniform(0.01, 0.02, 3)),
                            accel_bias_m_s2=tuple(rng.uniform(-0.15, 0.15, 3)),
                            accel_scale=tuple(rng.uniform(-0.02, 0.02, 3)),
                            gyro_noise=3e-4, accel_noise_m_s2=0.1, mag_latency_s=0.02)
    if board == "low-cost":
        return low_cost
    if board != "bad-accel":
        raise ValueError(f"unknown board {board!r}")
    return replace(low_cost, accel_bias_m_s2=tuple(rng.uniform(1.0, 2.0, 3) * rng.choice([-1.0, 1.0], 3)),
                   accel_scale=tuple(rng.uniform(0.05, 0.10, 3) * rng.choice([-1.0, 1.0], 3)))


def simulated(methods, seeds, mag_hz: float = 0.0) -> dict:
    """``{board: {kind: {method: (heading, inclination)}}}``: every kind of compass.sim.motion, 60 s,
    mean RMS over ``seeds`` (BROAD's metric over the moving samples); ``mag_hz``: the boards' magnetometer converts
    at that rate, each reading held on the rows until the next (0: a new reading every row)."""
    from compass.sample_check import new_readings
    from compass.sim.motion import KINDS, simulate_motion

    def errors(board, seed):
        return replace(board_errors(board, seed), mag_rate_hz=mag_hz)

    out = {}
    for board in ("broad-like", "low-cost"):
        out[board] = {}
        fitted = {}
        if any(m in methods for m in FITTED_CANDIDATES):
            for seed in seeds:  # the board's tumble recording: another motion seed, the rows at 1/6 of the rate
                cal = simulate_motion("fast_rotation", seed=500 + seed, errors=errors(board, seed))
                keep = np.zeros(len(cal.t_s), bool)
                keep[::6] = True
                if mag_hz > 0.0:  # its new readings, as compass.io.tumble reads a recording
                    keep = new_readings(cal.mag_ut)
                fitted[seed] = file_values(cal.t_s, cal.gyro_rad_s, cal.accel_m_s2, cal.mag_ut, keep)
                truth = 100 * (1 / (1 + np.asarray(board_errors(board, seed).gyro_scale)) - 1)
                print(f"  {board} seed {seed}: from its tumble file {_values_words(fitted[seed])} (true gyro matrix "
                      f"diag {', '.join(f'{v:+.2f}' for v in truth)} %)", flush=True)
        for kind in KINDS:
            runs = []
            for seed in seeds:
                trial = _Simulated(simulate_motion(kind, seed=seed, errors=errors(board, seed)), kind)
                trial.fitted = fitted.get(seed, NONE_FITTED)
                row = []
                for method in methods.values():
                    e = error_series(method(trial), trial.ref_quat_enu, trial.movement, trial.rate_hz)
                    row.append((e.heading_rms_deg, e.inclination_rms_deg))
                runs.append(row)
            out[board][kind] = dict(zip(methods, np.mean(runs, axis=0).tolist()))
            print(f"  {board} {kind}: " + ", ".join(f"{k} {v[0]:.2f}/{v[1]:.2f}" for k, v in out[board][kind].items()),
                  flush=True)
    return out


def simulated_section(available, peer_names, seeds: int, first_seed: int = 0, named=(), mag_hz: float = 0.0) -> None:
    """Print the simulated boards: VQF (when installed) beside the candidates ``named`` (``--candidates``),
    else :data:`SIM_CANDIDATES`; seeds ``first_seed`` to ``first_seed + seeds - 1``; ``mag_hz``: :func:`simulated`'s."""
    methods = {k: available[k] for k in peer_names[:1] + [c for c in named or SIM_CANDIDATES if c in available]}
    held = f", the magnetometer held at {mag_hz:g} Hz" if mag_hz else ""
    print(f"\nsimulated motions (compass.sim.motion, every kind, 60 s, seeds {first_seed}-{first_seed + seeds - 1}, "
          f"two boards{held}): heading RMS / inclination RMS, deg")
    sim = simulated(methods, range(first_seed, first_seed + seeds), mag_hz)
    _table("simulated groups (mean over the kinds)",
           {b: {m: tuple(np.mean([sim[b][k][m] for k in sim[b]], axis=0)) for m in methods} for b in sim}, list(methods))


# ---------------------------------------------------------------- diagnoses (issue 22)

def _run_with_state(trial, config, field):
    """run_filter's start and per-sample update, reading the nominal matrix and the inertial low-pass per sample."""
    from compass.filter import FilterStart, through_start

    n = len(trial)
    matrix, low_pass = np.full((n, 3, 3), np.nan), np.full((n, 3), np.nan)
    rows = list(zip(trial.t_s.tolist(), trial.accel_m_s2.tolist(), trial.gyro_rad_s.tolist(), field.tolist()))
    for filt, j in through_start(FilterStart(config), rows):
        if filt.update(*rows[j]):
            matrix[j], low_pass[j] = np.reshape(filt.matrix, (3, 3)), filt.low_pass
    return matrix, low_pass


def low_pass_inclination(trial, changes=None) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The scored rows (a mask) and, on them, the inclination error (deg) of the filter's output and of its inertial
    low-pass's direction applied outright (the filter's ``low_pass``: the tilt's measurement), the pipeline of
    :func:`ours` with the FilterConfig ``changes``."""
    from compass.evaluation import orientation_errors
    from compass.hard_iron import track_hard_iron

    config = ours_config(trial, trial.mag_ut, changes)
    field = track_hard_iron(trial.mag_ut, trial.accel_m_s2, trial.rate_hz, dip_deg=config.dip_deg).corrected(trial.mag_ut)
    matrix, low_pass = _run_with_state(trial, config, field)
    up = np.einsum("nij,nj->ni", matrix, low_pass)
    up /= np.linalg.norm(up, axis=1, keepdims=True)
    ok = np.all(np.isfinite(up), axis=1)
    tilted = np.full_like(matrix, np.nan)  # the smallest turn that puts the low-pass's direction on the vertical
    axis = np.cross(up[ok], [0.0, 0.0, 1.0])
    sin = np.linalg.norm(axis, axis=1)
    tilted[ok] = Rotation.from_rotvec(axis / np.maximum(sin, 1e-12)[:, None]
                                      * np.arctan2(sin, up[ok, 2])[:, None]).as_matrix() @ matrix[ok]
    scored = trial.movement & trial.ref_valid & ok
    ref = Rotation.from_quat(trial.ref_quat_enu[scored], scalar_first=True)

    def inclination(matrices):
        return orientation_errors(nwu_to_enu(Rotation.from_matrix(matrices[scored])), ref)[2]

    return scored, {"ours": inclination(matrix), "low-pass direction": inclination(tilted)}


def turn_diagnosis(trial) -> None:
    """Inclination RMS of the filter's output, of its inertial low-pass's direction applied outright, and of
    VQF, over the scored samples and by gyro rate |w| (rad/s)."""
    from compass.evaluation import orientation_errors

    scored, series = low_pass_inclination(trial)
    ref = Rotation.from_quat(trial.ref_quat_enu[scored], scalar_first=True)
    series["vqf"] = orientation_errors(Rotation.from_quat(vqf_online(trial)[scored], scalar_first=True), ref)[2]
    rate = np.linalg.norm(trial.gyro_rad_s[scored], axis=1)
    for lo, hi in ((0.0, np.inf), (0.0, 1.0), (1.0, 2.0), (2.0, np.inf)):
        k = (rate >= lo) & (rate < hi)
        if k.sum() < 100:
            continue
        print(f"  {trial.name[:30]:30s} |w| {lo:g}-{hi:g} rad/s ({100 * k.mean():3.0f} %): "
              + ", ".join(f"{name} {np.sqrt(np.mean(e[k] ** 2)):.3f}" for name, e in series.items()))


BANDS_S = (0.3, 1.0, 3.0, 10.0)
"""Edges of the time-scale bands of :func:`band_diagnosis`, s."""

NO_FIELD = {"field_tolerance": 1e-9, "gate_timeout_s": 1e9}
"""FilterConfig changes under which the gate refuses every field reading: the tilt from the gyro and accelerometer only."""


def _tilt_error_deg(quat_enu, ref_quat_enu) -> np.ndarray:
    """The world-frame tilt error (x, y of the error rotation ``q_est q_ref^-1``'s rotation vector), deg; 0 where
    either is missing (the rows are not scored)."""
    ok = np.all(np.isfinite(quat_enu), axis=1) & np.all(np.isfinite(ref_quat_enu), axis=1)
    out = np.zeros((len(ok), 2))
    e = Rotation.from_quat(quat_enu[ok], scalar_first=True) * Rotation.from_quat(ref_quat_enu[ok], scalar_first=True).inv()
    out[ok] = np.degrees(e.as_rotvec()[:, :2])
    return out


def _bands(error: np.ndarray, rows: np.ndarray, rate_hz: float) -> list[float]:
    """RMS over ``rows`` of a tilt error series split by time scale: what each moving mean of :data:`BANDS_S` removes
    from the one before (periods below 0.3 s, 0.3-1 s, ...), and what the longest leaves (above 10 s), deg."""
    from scipy.ndimage import uniform_filter1d

    out, rest = [], error
    for seconds in BANDS_S:
        smooth = uniform_filter1d(rest, max(1, int(round(seconds * rate_hz))), axis=0)
        out.append(float(np.sqrt(np.mean(np.sum((rest - smooth)[rows] ** 2, axis=1)))))
        rest = smooth
    return out + [float(np.sqrt(np.mean(np.sum(rest[rows] ** 2, axis=1))))]


def _motion_left_deg(trial) -> np.ndarray:
    """The tilt error the first-order inertial low-pass (``FilterConfig`` default time constant) would make from the
    motion acceleration alone: the accelerometer less gravity put into the housing by the *reference* attitude,
    turned into the world by it and low-passed there; horizontal part over g, deg (a truth-based diagnosis only)."""
    from scipy.signal import lfilter

    from compass.filter import FilterConfig

    ok = trial.ref_valid & np.all(np.isfinite(trial.ref_quat_enu), axis=1)
    index = np.maximum.accumulate(np.where(ok, np.arange(len(ok)), 0))
    index[:np.argmax(ok)] = np.argmax(ok)  # rows without a reference take the nearest earlier one (the first: the next)
    ref = Rotation.from_quat(trial.ref_quat_enu[index], scalar_first=True)
    motion_world = ref.apply(trial.accel_m_s2) - [0.0, 0.0, GRAVITY]
    tau = FilterConfig(field_norm=1.0, dip_deg=0.0, mag_noise=1.0).accel_time_constant_s
    alpha = -np.expm1(-1.0 / (trial.rate_hz * tau))
    return np.degrees(lfilter([alpha], [1.0, alpha - 1.0], motion_world[:, :2] / GRAVITY, axis=0))


def leak_time_scales(leak: np.ndarray, raw: np.ndarray, rows: np.ndarray, tau_s: float, rate_hz: float,
                     bandwidth_s: float = 1.0) -> tuple[float, float, float]:
    """Correlation times of a leak series (``--leak``), s: the observable estimate ``tau sqrt(<|q|^2> / <|r - q|^2>)``
    from the raw motion ``raw`` (``r = f - H f``, ``q = H r``, first order, time constant ``tau_s``: ``r - q = tau
    dq/dt``, so it is ``1 / w`` for a motion at ``w``), the leak's own time scale ``sqrt(<l^2> / <l'^2>)``, and the
    time ``N / (2 <l^2>)`` its density ``N = 2 T var(LP_T l)`` gives at a first-order ``T = bandwidth_s``; over
    ``rows``."""
    from scipy.signal import lfilter

    def low_pass(x, tau):
        alpha = -np.expm1(-1.0 / (rate_hz * tau))
        return lfilter([alpha], [1.0, alpha - 1.0], x, axis=0)

    q = low_pass(raw, tau_s)
    estimate = tau_s * np.sqrt(np.mean(q[rows] ** 2) / np.mean((raw - q)[rows] ** 2))
    rate = np.gradient(leak, 1.0 / rate_hz, axis=0)
    scale = np.sqrt(np.mean(leak[rows] ** 2) / np.mean(rate[rows] ** 2))
    density = 2.0 * bandwidth_s * np.mean(low_pass(leak, bandwidth_s)[rows] ** 2)
    return float(estimate), float(scale), float(density / (2.0 * np.mean(leak[rows] ** 2)))


def leak_diagnosis(trial) -> tuple[float, ...]:
    """The leak (``--leak``, truth-based, a diagnosis only): the horizontal motion acceleration over g (the
    accelerometer put into the world by the *reference* attitude, less gravity and less its mean over the first
    second of the initial rest, the accelerometer's own offset) through our first-order low-pass (``FilterConfig``
    default), then through a 1 s first-order pole as the Kalman gain adds, and through VQF's Butterworth
    (``tauAcc`` 3 s, its own coefficients): RMS per axis over the movement rows, deg; then the leak's correlation
    times (:func:`leak_time_scales`)."""
    from scipy.signal import lfilter
    from vqf import PyVQF

    from compass.filter import FilterConfig

    ok = trial.ref_valid & np.all(np.isfinite(trial.ref_quat_enu), axis=1)
    index = np.maximum.accumulate(np.where(ok, np.arange(len(ok)), 0))
    index[:np.argmax(ok)] = np.argmax(ok)
    world = Rotation.from_quat(trial.ref_quat_enu[index], scalar_first=True).apply(trial.accel_m_s2) / GRAVITY
    rest = slice(0, max(1, int(trial.rate_hz)))
    motion = world[:, :2] - world[rest, :2].mean(axis=0)
    tau = FilterConfig(field_norm=1.0, dip_deg=0.0, mag_noise=1.0).accel_time_constant_s

    def low_pass(x, t):
        alpha = -np.expm1(-1.0 / (trial.rate_hz * t))
        return lfilter([alpha], [1.0, alpha - 1.0], x, axis=0)

    ours = low_pass(motion, tau)
    b, a = PyVQF.filterCoeffs(3.0, 1.0 / trial.rate_hz)
    rows = trial.movement
    rms = [float(np.degrees(np.sqrt(np.mean(x[rows] ** 2))))
           for x in (ours, low_pass(ours, 1.0), lfilter(b, np.r_[1.0, a], motion, axis=0))]
    return tuple(rms) + leak_time_scales(ours, motion - ours, rows, tau, trial.rate_hz)


def band_diagnosis(trial) -> dict[str, tuple]:
    """Print the tilt error of the filter (defaults), of the filter with every field reading refused, and of VQF,
    RMS over the scored samples, split by time scale (:func:`_bands`), beside the motion acceleration the
    first-order inertial low-pass leaves (:func:`_motion_left_deg`).

    Returns
    -------
    dict
        ``{method: (heading RMS, inclination RMS, bands)}`` (BROAD's metric, deg; ``bands`` the :func:`_bands`
        list), and ``{"motion left by LP": (nan, nan, bands)}``.
    """
    runs = {"ours": ours()(trial), "ours, field refused": ours(NO_FIELD)(trial), "vqf": vqf_online(trial)}
    rows = trial.movement & trial.ref_valid
    out = {}
    for name, quat in runs.items():
        e = error_series(quat, trial.ref_quat_enu, trial.movement, trial.rate_hz)
        out[name] = (e.heading_rms_deg, e.inclination_rms_deg, _bands(_tilt_error_deg(quat, trial.ref_quat_enu), rows,
                                                                      trial.rate_hz))
    out["motion left by LP"] = (np.nan, np.nan, _bands(_motion_left_deg(trial), rows, trial.rate_hz))
    for name, (heading, inclination, cells) in out.items():
        rms = "" if np.isnan(heading) else f"{heading:6.3f} / {inclination:5.3f}"
        print(f"  {trial.name[:30]:30s} {name:20s} {rms:15s}  " + " ".join(f"{v:6.3f}" for v in cells), flush=True)
    return out


def bands_table(results: dict[str, dict]) -> str:
    """The groups' (:func:`_groups`) mean heading / inclination RMS and mean tilt-error bands, a markdown table."""
    groups = _groups(results)
    rows = []
    for group, trials in groups.items():
        for name in next(iter(results.values())):
            heading, inclination = (np.mean([results[t][name][k] for t in trials]) for k in (0, 1))
            bands = np.mean([results[t][name][2] for t in trials], axis=0)
            rms = "-" if np.isnan(heading) else f"{heading:.2f} / {inclination:.2f}"
            rows.append([f"{group} ({len(trials)})", name, rms] + [f"{v:.2f}" for v in bands])
    periods = [f"{lo:g}-{hi:g} s" for lo, hi in zip((0.0,) + BANDS_S, BANDS_S)] + [f"> {BANDS_S[-1]:g} s"]
    return markdown_table(["group", "method", "heading / inclination"] + periods, rows)


def start_parts(trial) -> None:
    """Heading / inclination RMS with each part of the one start (issue 22 item 2) switched back: the
    stream's reference (else the config's, the trial's initial rest), the window's first attitude (else
    the first row's), the bias hold (else none)."""
    from compass.filter import AttitudeFilter, run_filter
    from compass.hard_iron import track_hard_iron

    config = ours_config(trial, trial.mag_ut)
    field = track_hard_iron(trial.mag_ut, trial.accel_m_s2, trial.rate_hz, dip_deg=config.dip_deg).corrected(trial.mag_ut)
    free = replace(config, start_bias_hold=False)

    def first_row(cfg):  # the filter stepped from the first row, with the config's reference (before issue 22)
        f, quat = AttitudeFilter(cfg, gyro=True), np.full((len(trial), 4), np.nan)
        for i in range(len(trial)):
            if f.update(trial.t_s[i], trial.accel_m_s2[i], trial.gyro_rad_s[i], field[i]):
                quat[i] = Rotation.from_matrix(np.reshape(f.matrix, (3, 3))).as_quat()
        return quat

    runs = {"first row, config ref, no hold (before)": first_row(free),
            "window, config ref, no hold": run_filter(trial.t_s, trial.accel_m_s2, trial.gyro_rad_s, field, free,
                                                      reference="config").quat,
            "window, stream ref, no hold": run_filter(trial.t_s, trial.accel_m_s2, trial.gyro_rad_s, field, free).quat,
            "window, stream ref, hold (now)": run_filter(trial.t_s, trial.accel_m_s2, trial.gyro_rad_s, field, config).quat}
    from compass.evaluation import orientation_errors

    before, window = (runs[k] for k in list(runs)[:2])
    ok = np.all(np.isfinite(before), axis=1) & np.all(np.isfinite(window), axis=1)
    shift = orientation_errors(Rotation.from_quat(window[ok]), Rotation.from_quat(before[ok]))[1]
    t, moving_from = trial.t_s[ok], trial.t_s[trial.movement][0]
    at = dict(zip(("start", "movement", "movement + 20 s", "movement + 40 s"),
                  (trial.t_s[0], moving_from, moving_from + 20.0, moving_from + 40.0)))
    rest = ok & ~trial.movement & trial.ref_valid & (trial.t_s < moving_from)
    scored = ok & trial.movement & trial.ref_valid
    signed = {}
    for name, quat, rows in (("window at rest", window, rest), ("first row at rest", before, rest),
                             ("first row over the movement", before, scored)):
        enu = Rotation.from_quat(nwu_to_enu(Rotation.from_quat(quat[rows])).as_quat(scalar_first=True), scalar_first=True)
        signed[name] = orientation_errors(enu, Rotation.from_quat(trial.ref_quat_enu[rows], scalar_first=True))[1].mean()
    print(f"  {trial.name[:30]:30s} window start minus first-row start, heading (deg) at "
          + ", ".join(f"{k} {shift[min(np.searchsorted(t, x), len(t) - 1)]:+.3f}" for k, x in at.items())
          + f" (movement from {moving_from:.1f} s); mean signed heading error: "
          + ", ".join(f"{k} {v:+.3f}" for k, v in signed.items()))
    cells = []
    for name, quat in runs.items():
        ok = np.all(np.isfinite(quat), axis=1)
        enu = np.full_like(quat, np.nan)
        enu[ok] = nwu_to_enu(Rotation.from_quat(quat[ok])).as_quat(scalar_first=True)
        e = error_series(enu, trial.ref_quat_enu, trial.movement, trial.rate_hz)
        cells.append(f"{name} {e.heading_rms_deg:.4f}/{e.inclination_rms_deg:.4f}")
    print(f"  {trial.name[:30]:30s} " + " | ".join(cells))


# ---------------------------------------------------------------- timing

def cpu_us_per_sample(fn, n: int, repeat: int = 3) -> float:
    """Best-of-``repeat`` CPU time of ``fn()`` over ``n`` samples, microseconds per sample (CPU time:
    the machine is shared, wall time would count the others' work)."""
    best = np.inf
    for _ in range(repeat):
        t0 = time.process_time()
        fn()
        best = min(best, time.process_time() - t0)
    return 1e6 * best / n


def timings(trial) -> dict[str, float]:
    """Microseconds per sample of the toolkit's filter and the peers' per-sample and batch calls."""
    from compass.filter import AttitudeFilter, run_filter

    config = ours_config(trial, trial.mag_ut)
    gyr, acc, mag = _contiguous(trial)
    n, t = len(trial), trial.t_s
    out = {"ours run_filter (offline)": cpu_us_per_sample(lambda: run_filter(t, acc, gyr, mag, config), n)}

    def step_loop():  # what compass live does per sample: numpy rows in, an Estimate out
        f = AttitudeFilter(config, gyro=True)
        for i in range(n):
            f.step(t[i], acc[i], gyr[i], mag[i])

    out["ours step() per sample (live)"] = cpu_us_per_sample(step_loop, n, repeat=1)
    try:
        from vqf import VQF

        def vqf_loop():
            v = VQF(1.0 / trial.rate_hz)
            for i in range(n):
                v.update(gyr[i], acc[i], mag[i])
                v.getQuat9D()

        out["vqf per-sample loop"] = cpu_us_per_sample(vqf_loop, n)
        out["vqf updateBatch"] = cpu_us_per_sample(lambda: VQF(1.0 / trial.rate_hz).updateBatch(gyr, acc, mag), n)
    except ImportError as exc:
        print(f"skipping vqf timing: {exc}")
    try:
        out["imufusion per-sample loop"] = cpu_us_per_sample(lambda: fusion(trial), n)
    except ImportError as exc:
        print(f"skipping imufusion timing: {exc}")
    return out


def _contiguous(trial):
    return tuple(np.ascontiguousarray(a) for a in (trial.gyro_rad_s, trial.accel_m_s2, trial.mag_ut))


class _Synthetic:
    """A still sensor at a known orientation in a Berlin-like field (duck-types BroadTrial)."""

    def __init__(self, r_enu: Rotation, seconds: float = 20.0, rate_hz: float = 285.714):
        n = int(seconds * rate_hz)
        self.rate_hz = rate_hz
        self.t_s = np.arange(n) / rate_hz
        self.gyro_rad_s = np.zeros((n, 3))
        self.accel_m_s2 = np.tile(r_enu.apply([0.0, 0.0, GRAVITY], inverse=True), (n, 1))
        self.mag_ut = np.tile(r_enu.apply([0.0, 15.0, -40.0], inverse=True), (n, 1))  # north = ENU +Y, dip 69 deg
        self.movement = np.r_[np.zeros(n // 2, bool), np.ones(n - n // 2, bool)]
        self.ref_quat_enu = np.tile(r_enu.as_quat(scalar_first=True), (n, 1))

    def __len__(self):
        return len(self.t_s)


def check_frames(methods) -> dict[str, float]:
    """Worst heading + inclination error (deg) of each method on still synthetic sensors at known orientations."""
    cases = [Rotation.from_euler("ZYX", a, degrees=True) for a in ([30, 10, -20], [-120, -25, 40], [175, 5, 170])]
    worst = {}
    for name, method in methods.items():
        errors = []
        for r in cases:
            trial = _Synthetic(r)
            e = error_series(method(trial), trial.ref_quat_enu, trial.movement, trial.rate_hz)
            errors.append(max(e.heading_rms_deg, e.inclination_rms_deg))
        worst[name] = max(errors)
    return worst


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data", nargs="?", default=str(ROOT.parent / "shared" / "data" / "broad"))
    parser.add_argument("--trials", default="", help="comma-separated trial number prefixes (default: all)")
    parser.add_argument("--quick", action="store_true", help=f"trials {','.join(QUICK_TRIALS)} only")
    parser.add_argument("--cal", help="calibration JSON to add the 'ours + cal' column (fitted on other trials)")
    parser.add_argument("--skip-check", action="store_true", help="skip the synthetic frame check")
    parser.add_argument("--no-timing", action="store_true", help="skip the microseconds-per-sample section")
    parser.add_argument("--diagnose", action="store_true",
                        help="only the issue-22 diagnoses: inclination by turn rate, the start's parts switched back")
    parser.add_argument("--leak", action="store_true",
                        help="only the leak of the inertial low-passes (truth-based): ours, with a 1 s Kalman pole, "
                             "VQF's, and its correlation times, per trial")
    parser.add_argument("--bands", action="store_true",
                        help="only the inclination's time scales: ours, ours with the field refused, VQF, and the "
                             "motion the inertial low-pass leaves (truth-based), per trial and group")
    parser.add_argument("--candidates", default="",
                        help="comma-separated candidate names to run (default: every leave-one-out candidate); "
                             f"also {', '.join(TURN_VARIANTS)}")
    parser.add_argument("--peers", default="vqf,vqf offline,fusion,madgwick",
                        help="comma-separated peers to run (default: all four; the first is the simulated section's)")
    parser.add_argument("--sim-only", action="store_true", help="only the simulated boards (no BROAD trial)")
    parser.add_argument("--sim-seeds", type=int, default=2, help="seeds per kind of simulated motion (0: no simulation)")
    parser.add_argument("--latency-check", action="store_true",
                        help="only the simulated motions with a late magnetometer alone, compensated or not")
    parser.add_argument("--sim-first-seed", type=int, default=0,
                        help="the first simulated seed (judge a change on seeds it was not developed on)")
    parser.add_argument("--sim-mag-hz", type=float, default=0.0,
                        help="the simulated boards' magnetometer rate, Hz: each reading held until the next (default: "
                             "a new reading every row)")
    args = parse_args(parser, argv)
    if args.write_docs and not args.bands:
        parser.error("--write-docs writes the --bands table only: use it with --bands")

    peers = {"vqf": vqf_online, "vqf offline": vqf_offline, "fusion": fusion, "madgwick": madgwick}
    wanted_peers = [p.strip() for p in args.peers.split(",") if p.strip()]
    if any(p not in peers for p in wanted_peers):
        parser.error(f"--peers: unknown {[p for p in wanted_peers if p not in peers]} (known: {', '.join(peers)})")
    peers = {p: peers[p] for p in wanted_peers}
    available = {}
    for name, method in peers.items():
        try:
            method(_Synthetic(Rotation.identity(), seconds=0.1))
            available[name] = method
        except ImportError as exc:
            print(f"skipping {name}: {exc} (pip install -e '.[bench]')")
    peer_names = list(available)
    chosen = [c.strip() for c in args.candidates.split(",") if c.strip()] or list(CANDIDATES)
    unknown = [c for c in chosen if c not in CANDIDATES | TURN_VARIANTS]
    if unknown or "defaults" not in chosen:
        parser.error(f"--candidates: unknown {unknown}" if unknown else "--candidates must include defaults")
    candidates = {name: ours(*(CANDIDATES | TURN_VARIANTS)[name]) for name in chosen}
    named = chosen if args.candidates else ()
    available |= candidates
    if args.cal:
        available["ours + cal"] = ours(model=load_calibration(args.cal).model)

    print(METRIC + "; no heading offset removed; group = mean of its trials' RMS")
    if not args.skip_check:
        # a calibration (fitted to a real sensor) rightly changes a perfect synthetic field: frames are
        # checked on the uncalibrated methods, whose conversions the calibrated ones share
        worst = check_frames({k: available[k] for k in peer_names + ["defaults"]})
        print("frame check (still synthetic sensor, 3 orientations), worst error deg: "
              + ", ".join(f"{k} {v:.2f}" for k, v in worst.items()))
        bad = [k for k, v in worst.items() if v > 1.0]
        if bad:
            print(f"frame check failed for {', '.join(bad)}: fix the conversion before trusting numbers")
            return 1

    if args.latency_check:
        latency_check(range(max(args.sim_seeds, 1)))
        return 0
    if args.sim_only:
        simulated_section(available, peer_names, max(args.sim_seeds, 1), args.sim_first_seed, named, args.sim_mag_hz)
        return 0

    files = sorted(Path(args.data).glob("*.mat"))
    wanted = [p for p in args.trials.split(",") if p] or (list(QUICK_TRIALS) if args.quick else [])
    files = [f for f in files if not wanted or any(f.name.startswith(p) for p in wanted)]
    if not files:
        print(f"no BROAD trials in {args.data}")
        return 2

    if args.leak:
        print("leak per axis over the movement rows, deg: our first-order low-pass, with a 1 s Kalman pole, VQF's "
              "Butterworth 3 s; its correlation time, s: observable estimate / true time scale / at a 1 s bandwidth")
        for f in files:
            trial = read_broad(f)
            print(f"  {trial.name[:36]:36s} " + " ".join(f"{v:5.2f}" for v in leak_diagnosis(trial)))
        return 0
    if args.bands:
        print("tilt error by time scale, deg: heading / inclination RMS (BROAD's metric), then the world-frame tilt "
              "error's RMS over the scored samples by period: " + ", ".join(
                  f"{lo:g}-{hi:g} s" for lo, hi in zip((0.0,) + BANDS_S, BANDS_S)) + f", above {BANDS_S[-1]:g} s")
        results = {}
        for f in files:
            trial = read_broad(f)
            results[trial.name] = band_diagnosis(trial)
        publish(args, "docs/benchmarks.md", "bench_broad.bands", bands_table(results),
                "mean over each group's trials of heading / inclination RMS (BROAD's metric) and of the world-frame "
                "tilt error's RMS by period (moving means' differences), deg")
        return 0
    if args.diagnose:
        print("inclination RMS, deg: the filter, its inertial low-pass's direction applied outright, VQF, by |w|")
        for f in files:
            turn_diagnosis(read_broad(f))
        print("\nheading / inclination RMS, deg, the one start's parts switched back")
        for f in files:
            start_parts(read_broad(f))
        return 0

    print("\nnoise on each trial's initial rest (first half) vs FilterConfig defaults (generic MEMS figures)")
    from compass.filter import FilterConfig

    default = FilterConfig(field_norm=1.0, dip_deg=0.0, mag_noise=1.0)
    fitted = broad_fitted(Path(args.data)) if any(c in candidates for c in FITTED_CANDIDATES) else {}
    results, trials, noises = {}, {}, []
    for f in files:
        trial = read_broad(f)
        BROAD_FITTED[trial.name] = held_out(trial.name, fitted)
        trials[trial.name] = trial
        noises.append(rest_noise(trial.gyro_rad_s, trial.accel_m_s2, trial.mag_ut, ~trial.movement, trial.rate_hz))
        row = {}
        for name, method in available.items():
            e = error_series(method(trial), trial.ref_quat_enu, trial.movement, trial.rate_hz)
            row[name] = (e.heading_rms_deg, e.inclination_rms_deg)
        results[trial.name] = row
        noise = noises[-1]
        print(f"  {trial.name}: gyro {noise.gyro_noise:.2e} rad/s/sqrt(Hz), accel {noise.accel_noise:.4f} g, "
              f"mag {noise.mag_noise:.2f} uT; " + ", ".join(f"{k} {row[k][0]:.2f}/{row[k][1]:.2f}"
                                                          for k in peer_names[:1] + ["defaults"]), flush=True)
    print(f"  median: gyro {np.median([n.gyro_noise for n in noises]):.2e} (default {default.gyro_noise:.1e}), "
          f"accel {np.median([n.accel_noise for n in noises]):.4f} (default {default.accel_noise}), "
          f"mag {np.median([n.mag_noise for n in noises]):.2f} uT (each trial's own, as compass evaluate)")

    names = [c for c in candidates if c in CANDIDATES]  # the turn variants are printed, never chosen
    choice = {t: loo_choice(results, t, names) for t in results}
    print(f"\nchosen on all {len(results)} trials (what the defaults should be): {loo_choice(results, None, names)}")
    for t in results:
        results[t]["ours LOO"] = results[t][choice[t]]
    columns = peer_names + ["defaults", "ours LOO"] + (["ours + cal"] if args.cal else [])
    _table("held out (LOO): each trial scored with the candidate chosen on the others", results, columns,
           extra={t: choice[t] for t in results})
    groups = _groups(results)
    _table("groups (mean of the trials' RMS)", {g: _mean(results, ts, columns) for g, ts in groups.items()}, columns)
    losses = {g: sum(results[t]["ours LOO"][0] > results[t]["vqf"][0] for t in ts) for g, ts in groups.items()} \
        if "vqf" in peer_names else {}
    if losses:
        print("ours LOO heading above VQF's on: " + ", ".join(f"{g} {k}/{len(groups[g])}" for g, k in losses.items()))

    if args.candidates:
        _table("every trial, each chosen candidate (--candidates)", results, peer_names[:1] + list(candidates))
    print("\nablation (one mechanism removed) and constants (half, twice), every trial, not held out: "
          "heading RMS / inclination RMS, deg")
    _ablation(results, list(candidates), groups | {"all": list(results)})

    if args.sim_seeds > 0:
        simulated_section(available, peer_names, args.sim_seeds, args.sim_first_seed, named, args.sim_mag_hz)

    if not args.no_timing:
        first = trials.get("01_undisturbed_slow_rotation_A", next(iter(trials.values())))
        print(f"\nmicroseconds per sample (CPU time, best of 3; {first.name}, {len(first)} samples)")
        for name, us in timings(first).items():
            print(f"  {name:32s} {us:7.2f}")
    return 0


def _groups(results) -> dict[str, list[str]]:
    groups = {"undisturbed": [], "disturbed": [], "attached_magnet": []}
    for t in results:
        kind = t.split("_", 1)[1]
        for g in groups:
            if kind.startswith(g) or f"_{g}" in f"_{kind}":
                groups[g].append(t)
    return {g: ts for g, ts in groups.items() if ts}


def _mean(results, trials, columns) -> dict[str, tuple[float, float]]:
    return {c: tuple(np.mean([results[t][c] for t in trials], axis=0)) for c in columns}


def _table(title, rows, columns, extra=None):
    """One row per trial or group, ``heading / inclination`` cells; ``extra``: a last column of words."""
    print(f"\n{title}")
    print(f"{'':44s} " + " ".join(f"{c:>15s}" for c in columns) + ("   choice" if extra else ""))
    for name, row in rows.items():
        print(f"{name:44s} " + " ".join(f"{row[c][0]:7.3f} /{row[c][1]:6.3f}".rjust(15) for c in columns)
              + (f"   {extra[name]}" if extra else ""))


def _ablation(results, candidates, groups):
    """One row per candidate, one ``heading / inclination`` column per group."""
    means = {g: _mean(results, ts, candidates) for g, ts in groups.items()}
    print(f"{'candidate':28s} " + " ".join(f"{g + f' ({len(ts)})':>19s}" for g, ts in groups.items()))
    for c in candidates:
        print(f"{c:28s} " + " ".join(f"{means[g][c][0]:8.3f} /{means[g][c][1]:6.3f}".rjust(19) for g in groups))


if __name__ == "__main__":
    sys.exit(main())
