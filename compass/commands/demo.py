"""``compass demo``: the main job on built-in simulated data, end to end.

Simulates a four-flip bench session, calibrates it (with the residual diagnosis) and prints the
report; then simulates the calibrated module in random attitudes, solves heading, pitch and roll
with the calibration and compares them with the truth.  Then on from the bench: the module is
built into a product with its own iron, the installation is calibrated on top of the bench model
from a tumble, and the product is used at another site (true north from the WMM there); each step
prints its heading error beside what the true sensor gives on the same rows.

Each step is one function taking and returning a :class:`Demo` (the files so far), so a step can be
added between others.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import limits

ANOTHER_SITE = "-33.87,151.21"  # Sydney: the field points up, dip about -64 deg
DATE = "2026-06-01"


@dataclass
class Demo:
    """What the steps share: the folder, the seed, the bench's truth and the files written so far."""

    folder: Path
    seed: int
    effects: tuple
    truth: dict = field(default_factory=dict)
    files: dict = field(default_factory=dict)
    results: dict = field(default_factory=dict)


def register(sub) -> None:
    p = sub.add_parser("demo", help="simulate a bench session, calibrate it, solve attitude, print the report")
    p.add_argument("--seed", type=limits.SEED.option("--seed"), default=1, help="random seed (default 1)")
    p.add_argument("--effect", action="append", default=[], help="inject a simulator effect (repeatable)")
    p.add_argument("--workdir", default=None, help="keep the files here (default: a temporary folder)")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..sim.fourflip import SIM_EFFECTS

    unknown = set(args.effect) - set(SIM_EFFECTS)
    if unknown:
        from ..cli import BadInput

        raise BadInput(f"unknown effect(s) {sorted(unknown)}; known: {', '.join(SIM_EFFECTS)}")
    demo = Demo(Path(args.workdir or tempfile.mkdtemp(prefix="compass-demo-")), args.seed, tuple(args.effect))
    for step in STEPS:
        step(demo)
    print(f"files in {demo.folder} (plots in {demo.folder / 'report'})")
    return 0


def bench(demo: Demo) -> Demo:
    """Steps 1-2: a four-flip bench session, calibrated, against the simulator's truth."""
    from ..calibration import load
    from ..frames import direction_sigma_deg
    from ..sim.fourflip import simulate_fourflip, write_fourflip
    from . import calibrate as calibrate_cmd

    folder = demo.folder
    session = simulate_fourflip(seed=demo.seed, effects=demo.effects)
    rec_path, _ = write_fourflip(session, folder / "bench.csv", force=True)
    print(f"1. simulated a four-flip bench session: {rec_path}"
          + (f" (effects the estimator is not told about: {', '.join(demo.effects)})" if demo.effects else ""))
    cal_path = folder / "cal.json"
    print("2. calibrating it (joint maximum likelihood, residual diagnosis):")
    cal_result = calibrate_cmd.calibrate_file(rec_path, cal_path, report=folder / "report", force=True)
    cal = load(cal_path)
    model, truth = cal.model, session.truth
    print("   against the simulator's truth (the estimator never saw it):")
    for name, true_dir in zip(truth["channels"], truth["directions"]):
        c = model.channels.index(name)
        err = np.degrees(np.arccos(np.clip(np.dot(model.directions[c], true_dir), -1.0, 1.0)))
        sigma = direction_sigma_deg(model.direction_covariance[c])
        print(f"   {name}: direction error {err:.4f} deg (reported sigma {sigma:.4f} deg)")
    print(f"   dip error {model.dip_deg - truth['dip_deg']:+.4f} deg "
          f"(reported sigma {cal.provenance.dip_sigma_deg:.4f} deg)")
    demo.truth, demo.files["bench"], demo.files["bench_recording"] = truth, cal_path, rec_path
    demo.results["bench"] = cal_result
    return demo


def attitude(demo: Demo) -> Demo:
    """Step 3: the calibrated module in random attitudes at the bench's site."""
    from ..sim.runtime import simulate_runtime, write_runtime
    from . import attitude as attitude_cmd

    print("3. solving attitude: the module in 2000 random attitudes (pitch, roll within +-80 deg):")
    runtime = simulate_runtime(demo.truth, 2000, seed=demo.seed)
    run_path, _ = write_runtime(runtime, demo.folder / "runtime.csv", force=True)
    att = attitude_cmd.attitude_file(demo.files["bench"], run_path, demo.folder / "attitude.csv", force=True)
    heading_err = _wrap(att.heading_deg - runtime.heading_deg)
    print(f"   heading RMS error {_rms(heading_err):.3f} deg "
          f"(propagated 1-sigma {_rms(att.heading_sigma_deg):.3f} deg), "
          f"pitch {_rms(att.pitch_deg - runtime.pitch_deg):.3f} deg, roll {_rms(att.roll_deg - runtime.roll_deg):.3f} deg")
    demo.files["runtime"] = run_path
    demo.results.update(attitude=att, runtime=runtime)
    return demo


def record(demo: Demo) -> Demo:
    """Step 4: demo.rrd, the calibration, the attitude and its errors in Rerun (when rerun-sdk is installed)."""
    path = demo.folder / "demo.rrd"
    try:
        from ..viz.demo import record_demo
    except ImportError:
        print("4. (pip install 'compass-toolkit[rerun]' to also get demo.rrd, the whole run in the Rerun viewer)")
        return demo
    from ..calibration import load
    from .calibrate import _base_residuals

    cal_result, att, runtime = demo.results["bench"], demo.results["attitude"], demo.results["runtime"]
    record_demo(path, demo.files["bench_recording"], cal_result, att, load(demo.files["bench"]).model,
                t_s=runtime.t_s, raw=runtime.outputs, accel=runtime.accel, truth_heading_deg=runtime.heading_deg,
                truth_pitch_deg=runtime.pitch_deg, truth_roll_deg=runtime.roll_deg,
                base_residuals=_base_residuals(cal_result))
    print(f"4. wrote {path}: the calibration, the attitude and its errors against the truth; open it with "
          f"`rerun {path}` (pip install 'compass-toolkit[rerun]' installs the viewer)")
    return demo


def installation(demo: Demo) -> Demo:
    """Steps 5-7: into a product, the installation calibrated from a tumble, used at another site."""
    from ..installed import installed_model
    from ..site import Site
    from ..sim.installation import random_installation, simulate_installation, true_model, write_installation
    from . import attitude as attitude_cmd
    from . import calibrate as calibrate_cmd

    folder, truth = demo.folder, demo.truth
    inst = random_installation(demo.seed)
    best_model = installed_model(true_model(truth), inst.hard_iron_ut, inst.soft_iron)
    h = inst.hard_iron_ut
    print(f"5. the module built into a product: its iron adds {np.linalg.norm(h):.1f} uT of hard iron "
          f"({h[0]:+.2f}, {h[1]:+.2f}, {h[2]:+.2f}) and a few % of soft iron; in random attitudes (pitch, roll "
          f"+-30 deg) with the bench calibration alone:")
    here = simulate_installation(truth, inst, kind="runtime", n=2000, max_tilt_deg=30.0, seed=demo.seed + 1)
    here_path, _ = write_installation(here, folder / "product.csv", force=True)
    att = attitude_cmd.attitude_file(demo.files["bench"], here_path, folder / "product_attitude.csv", force=True)
    print(f"   heading RMS error {_rms(_wrap(att.heading_deg - here.heading_deg)):.3f} deg (the true installed "
          f"sensor on the same rows: {_heading_rms(best_model, here):.3f} deg)")

    print("6. calibrating the installation on top of the bench model from a tumble of the product:")
    tumble = simulate_installation(truth, inst, kind="tumble", n=2000, seed=demo.seed + 2)
    tumble_path, _ = write_installation(tumble, folder / "install.csv", force=True)
    installed = folder / "installed.json"
    result = calibrate_cmd.calibrate_file(tumble_path, installed, base=demo.files["bench"], force=True, quiet=True)
    for line in result.report().splitlines()[:4]:
        print(f"   {line}")
    err = result.hard_iron_ut - inst.hard_iron_ut
    print(f"   hard iron error ({err[0]:+.3f}, {err[1]:+.3f}, {err[2]:+.3f}) uT against the truth "
          f"(sigma {result.hard_iron_sigma_ut.max():.3f} uT; the bench model's own offset errors are part of it)")

    site = Site.parse(ANOTHER_SITE, DATE)
    wmm = site.field()
    print(f"7. using the product at another site ({site}: WMM dip {wmm.dip_deg:.1f} deg, |B| {wmm.field_ut:.1f} uT, "
          f"declination {wmm.declination_deg:+.2f} deg; the bench had dip {truth['dip_deg']:.1f}, |B| "
          f"{truth['field_ut']:.0f}):")
    there = simulate_installation(truth, inst, kind="runtime", n=2000, max_tilt_deg=30.0, dip_deg=wmm.dip_deg,
                                  field_ut=wmm.field_ut, seed=demo.seed + 3)
    there_path, _ = write_installation(there, folder / "elsewhere.csv", force=True)
    best = _heading_rms(best_model, there)
    for name, label, cal, kwargs in (
            ("bench", "bench calibration only", demo.files["bench"], {}),
            ("installed", "installed, nothing said", installed, {}),
            ("installed_site", f"installed, --site {ANOTHER_SITE}", installed, {"site": ANOTHER_SITE, "date": DATE})):
        att = attitude_cmd.attitude_file(cal, there_path, folder / f"elsewhere_{name}.csv", force=True, **kwargs)
        text = (f"   {label}: heading RMS error {_rms(_wrap(att.heading_deg - there.heading_deg)):.3f} deg (true "
                f"installed sensor: {best:.3f} deg), {100 * att.disturbed.mean():.1f} % rows disturbed")
        if att.heading_true_deg is not None:
            true_north = _wrap(att.heading_true_deg - (there.heading_deg + wmm.declination_deg))
            text += f"; true heading RMS error {_rms(true_north):.3f} deg"
        print(text)
    demo.files.update(installed=installed, elsewhere=there_path)
    return demo


STEPS = (bench, attitude, record, installation)
"""The demo's steps, in order (each ``step(demo) -> demo``)."""


def _heading_rms(model, rec) -> float:
    from ..attitude import solve_attitude

    return _rms(_wrap(solve_attitude(model, rec.outputs, accel=rec.accel).heading_deg - rec.heading_deg))


def _wrap(d):
    return np.mod(np.asarray(d) + 180.0, 360.0) - 180.0


def _rms(v) -> float:
    return float(np.sqrt(np.mean(np.square(v))))
