"""``compass simulate fourflip|platform3d|tumble|reference|runtime|installation``: a simulated recording and its truth.

Each kind writes SPEC section 2's recording and, beside it, the truth the simulator used
(``<stem>.truth.json``, every kind; the runtime kinds' true angles per row under ``heading_deg``,
``pitch_deg``, ``roll_deg``).  The simulators are imported when a kind runs, not when the parser is built.
"""

from __future__ import annotations

from .. import limits
from ..limits import Range

SIM_EFFECTS = ("nonlinear_response", "encoder_error", "offset_drift", "platform_field", "flip_error", "turntable_zero",
               "temperature",
               "field_gradient", "gain_drift")
"""The four-flip simulator's effects (``compass.sim.fourflip.SIM_EFFECTS``, checked equal in the tests)."""


def register(sub) -> None:
    p = sub.add_parser("simulate", help="write simulated recordings (with their truth beside them)")
    kinds = p.add_subparsers(dest="kind", required=True, metavar="KIND")
    ff = _kind(kinds, "fourflip", "a four-flip turntable session (seed 000)", run_fourflip)
    ff.add_argument("--channels", type=limits.CHANNELS.option("--channels"),
                    default=3, help="number of single-axis channels (default 3)")
    ff.add_argument("--effect", action="append", default=[], choices=SIM_EFFECTS,
                    help="inject an effect (repeatable); the truth file records its parameters")
    ff.add_argument("--noise-ut", type=limits.NOISE_UT.option("--noise-ut"),
                    default=0.15, help="white noise, uT (default 0.15)")
    ff.add_argument("--field-ut", type=limits.FIELD_UT.option("--field-ut"), default=50.0, help="|B|, uT (default 50)")
    ff.add_argument("--dip-deg", type=limits.DIP_DEG.option("--dip-deg"),
                    default=None, help="dip, deg (default: random 40..70)")
    ff.add_argument("--step-deg", type=Range(0.0, 30.0, "deg", lo_open=True).option("--step-deg"),
                    default=1.0, help="turntable step, deg (default 1)")
    ff.add_argument("--effect-scale", type=limits.SCALE.option("--effect-scale"),
                    default=1.0, help="multiply every effect size")
    ff.add_argument("--accel-misalign-deg", type=Range(0.0, 90.0, "deg").option("--accel-misalign-deg"), default=None,
                    help="record ax,ay,az from an accelerometer misaligned with the housing by this RMS per axis, deg "
                         "(default: no accelerometer)")
    ff.add_argument("--turntable-tilt-deg",
                    type=Range(0.0, 10.0, "deg", hi_open=True).option("--turntable-tilt-deg"), default=0.0,
                    help="tilt the turntable's axis from the vertical by this angle, deg (default 0)")
    p3 = _kind(kinds, "platform3d", "a 3-D platform session with a tilt sensor (seed 001)", run_platform3d)
    p3.add_argument("--poses", choices=("grid", "random", "turntable"), default="grid",
                    help="platform poses (default grid; turntable never tilts and cannot be calibrated)")
    p3.add_argument("--tilt-axes", type=int, choices=(2, 3), default=2, help="tilt sensor axes (default 2)")
    tu = _kind(kinds, "tumble", "a free-motion (tumble) session: magnetometer with hard and soft iron, "
                                "accelerometer", run_tumble)
    tu.add_argument("--samples", type=Range(12, limits.SAMPLES.hi, integer=True).option("--samples"),
                    default=3000, help="rows (default 3000)")
    tu.add_argument("--rate-hz", type=limits.RATE_HZ.option("--rate-hz"),
                    default=50.0, help="row rate, Hz (default 50)")
    tu.add_argument("--field-ut", type=limits.FIELD_UT.option("--field-ut"), default=50.0, help="|B|, uT (default 50)")
    tu.add_argument("--coverage", choices=("full", "upright"), default="full",
                    help="full: every orientation (default); upright: never turned over")
    tu.add_argument("--no-accel", action="store_true", help="record no accelerometer")
    rf = _kind(kinds, "reference", "reference fields applied to a sensor array (seed 003)", run_reference)
    rf.add_argument("--sensors", type=limits.CHANNELS.option("--sensors"),
                    default=2, help="three-axis sensors in the array (default 2)")
    rf.add_argument("--fields", type=_ROWS.option("--fields"), default=12, help="reference fields applied (default 12)")
    rf.add_argument("--repeats", type=_ROWS.option("--repeats"), default=1, help="rows per field (default 1)")
    rf.add_argument("--field-ut", type=limits.FIELD_UT.option("--field-ut"),
                    default=50.0, help="field magnitude, uT (default 50)")
    ru = _kind(kinds, "runtime", "an attitude recording of a bench-calibrated sensor in random attitudes "
                                 "(true angles in <stem>.truth.json)", run_runtime)
    ru.add_argument("--truth", metavar="BENCH.truth.json",
                    help="the sensor: a four-flip truth file (compass simulate fourflip writes one beside its "
                         "recording; default: the four-flip simulator's sensor for --seed)")
    ru.add_argument("--samples", type=limits.SAMPLES.option("--samples"), default=1000, help="rows (default 1000)")
    ru.add_argument("--max-tilt-deg", type=limits.TILT_DEG.option("--max-tilt-deg"),
                    default=80.0, help="largest pitch and roll, deg (default 80)")
    ru.add_argument("--no-accel", action="store_true", help="record no accelerometer")
    ins = _kind(kinds, "installation", "a bench-calibrated sensor built into a product with its own iron "
                                       "(SPEC's installation recording: tumble, swing, or runtime rows to check "
                                       "an installed calibration)", run_installation)
    ins.add_argument("--truth", metavar="BENCH.truth.json",
                     help="the sensor: a four-flip truth file (default: the four-flip simulator's sensor for --seed)")
    ins.add_argument("--kind", choices=("tumble", "swing", "runtime"), default="tumble",
                     help="tumble: every orientation (default); swing: heading through 360 deg within "
                          "--max-tilt-deg (0: level); runtime: random headings within --max-tilt-deg")
    ins.add_argument("--samples", type=limits.SAMPLES.option("--samples"), default=2000, help="rows (default 2000)")
    ins.add_argument("--max-tilt-deg", type=limits.TILT_DEG.option("--max-tilt-deg"), default=10.0,
                     help="swing and runtime: largest pitch and roll, deg (default 10)")
    ins.add_argument("--hard-iron-ut", type=limits.IRON_UT.option("--hard-iron-ut"), default=6.0,
                     help="the product's hard iron, uT (about; random direction; default 6)")
    ins.add_argument("--soft-iron", type=Range(0.0, 0.5, hi_open=True).option("--soft-iron"), default=0.03,
                     help="the product's symmetric soft iron, entries about this far from the identity (default 0.03)")
    ins.add_argument("--yaw-deg", type=limits.ANGLE_DEG.option("--yaw-deg"),
                     default=0.0, help="the housing turned in the product, deg (default 0)")
    ins.add_argument("--heading-ref-sigma-deg", type=Range(0.0, 180.0, "deg").option("--heading-ref-sigma-deg"),
                     default=None,
                     help="also write heading_ref_deg, the product's true heading with this noise, deg")
    ins.add_argument("--base", metavar="BENCH.json",
                     help="the bench calibration, named in the recording's '# base:' metadata")
    fl = kinds.add_parser("fleet", help="a production line: --n modules' four-flip sessions on one bench, a few "
                                        "with named defects, the bench drifting after a session (truth in "
                                        "DIR/fleet_truth.json)")
    fl.add_argument("--out", required=True, metavar="DIR", help="folder for the recordings and fleet_truth.json")
    fl.add_argument("--n", type=Range(1, 100_000, integer=True).option("--n"), default=200,
                    help="modules, one session each (default 200)")
    fl.add_argument("--seed", type=limits.SEED.option("--seed"), default=0, help="random seed (default 0)")
    fl.add_argument("--defect-rate", type=limits.FRACTION.option("--defect-rate"), default=0.06,
                    help="fraction of modules with a named defect (default 0.06; at least one of each)")
    fl.add_argument("--drift-start", type=Range(0, 100_000, integer=True).option("--drift-start"), default=None,
                    help="session index where the bench's field starts to turn (default: two thirds of --n)")
    fl.add_argument("--drift-deg-per-session", type=Range(-10.0, 10.0, "deg").option("--drift-deg-per-session"),
                    default=0.02,
                    help="how fast the bench's dip moves after --drift-start, deg a session (default 0.02)")
    fl.add_argument("--step-deg", type=Range(0.0, 30.0, "deg", lo_open=True).option("--step-deg"), default=4.0,
                    help="turntable step, deg (default 4)")
    fl.add_argument("--force", action="store_true", help="overwrite existing files")
    fl.set_defaults(func=run_fleet)


_ROWS = Range(1, 100_000, integer=True)
"""Reference fields, or rows per field."""


def _kind(kinds, name: str, help_text: str, func):
    p = kinds.add_parser(name, help=help_text)
    p.add_argument("--out", required=True, help="recording CSV to write; the truth goes beside it (<stem>.truth.json)")
    p.add_argument("--seed", type=limits.SEED.option("--seed"), default=0, help="random seed (default 0)")
    p.add_argument("--force", action="store_true", help="overwrite existing files")
    p.set_defaults(func=func)
    return p




def run_fourflip(args) -> int:
    from ..sim.fourflip import SimAccelerometer, simulate_fourflip, write_fourflip

    accelerometer = None if args.accel_misalign_deg is None else SimAccelerometer(misalign_deg=args.accel_misalign_deg)
    session = simulate_fourflip(
        seed=args.seed, n_channels=args.channels, effects=tuple(args.effect), noise_ut=args.noise_ut,
        field_ut=args.field_ut, dip_deg=args.dip_deg, step_deg=args.step_deg, effect_scale=args.effect_scale,
        accelerometer=accelerometer, turntable_tilt_deg=args.turntable_tilt_deg,
    )
    rec, truth = write_fourflip(session, args.out, force=args.force)
    print(f"wrote {rec} ({session.outputs.shape[0]} samples, {len(session.channels)} channels"
          f"{', effects: ' + ', '.join(args.effect) if args.effect else ''}) and {truth}")
    return 0


def run_fleet(args) -> int:
    import sys

    from ..sim.fleet import FleetOptions, simulate_fleet

    options = FleetOptions(n=args.n, seed=args.seed, defect_rate=args.defect_rate, drift_start=args.drift_start,
                           drift_deg_per_session=args.drift_deg_per_session, step_deg=args.step_deg)
    truth = simulate_fleet(args.out, options, force=args.force,
                           progress=lambda line: print(line, file=sys.stderr, flush=True))
    bad = [m for m in truth["modules"] if m["should_fail"]]
    print(f"wrote {len(truth['modules'])} sessions into {args.out}: {len(bad)} with defects "
          f"({', '.join(sorted({m['defect'] for m in bad}))}); the bench drifts from session "
          f"{truth['drift']['start_session']}; truth in {args.out}/fleet_truth.json")
    return 0


def run_platform3d(args) -> int:
    from ..sim.platform3d import simulate_platform3d, write_platform3d

    sim = simulate_platform3d(seed=args.seed, poses=args.poses, tilt_axes=args.tilt_axes)
    rec, truth = write_platform3d(sim, args.out, force=args.force)
    print(f"wrote {rec} ({len(sim.mag)} samples) and {truth}")
    return 0


def run_tumble(args) -> int:
    from ..sim.tumble import simulate_tumble, write_tumble

    sim = simulate_tumble(seed=args.seed, n=args.samples, rate_hz=args.rate_hz, field_ut=args.field_ut,
                          coverage=args.coverage)
    rec, truth = write_tumble(sim, args.out, force=args.force, accel=not args.no_accel)
    print(f"wrote {rec} ({len(sim.mag)} samples, coverage {args.coverage}) and {truth}")
    return 0


def run_reference(args) -> int:
    from ..sim.reference import simulate_reference, write_reference

    from ..cli import BadInput

    if args.fields * args.repeats > limits.SAMPLES.hi:
        raise BadInput(f"--fields {args.fields} times --repeats {args.repeats} is more than "
                       f"{limits.SAMPLES.hi} rows")
    sim = simulate_reference(seed=args.seed, n_sensors=args.sensors, n_fields=args.fields, repeats=args.repeats,
                             field_ut=args.field_ut)
    rec, truth = write_reference(sim, args.out, force=args.force)
    print(f"wrote {rec} ({len(sim.reference)} rows, {args.sensors} sensors) and {truth}")
    return 0


def _bench_truth(args) -> dict:
    """The bench sensor: ``--truth`` (a four-flip truth file) or the four-flip simulator's for ``--seed``."""
    from ..cli import BadInput

    if args.truth is None:
        from ..sim.fourflip import simulate_fourflip

        return simulate_fourflip(seed=args.seed).truth
    from ..sim.truth import read_bench_truth

    try:
        return read_bench_truth(args.truth)
    except ValueError as exc:
        raise BadInput(str(exc)) from None


def run_installation(args) -> int:
    from ..sim.installation import random_installation, simulate_installation, write_installation

    truth = _bench_truth(args)
    installation = random_installation(args.seed, hard_iron_ut=args.hard_iron_ut, soft_iron=args.soft_iron,
                                       yaw_deg=args.yaw_deg)
    rec = simulate_installation(truth, installation, kind=args.kind, n=args.samples, max_tilt_deg=args.max_tilt_deg,
                                heading_ref_sigma_deg=args.heading_ref_sigma_deg, seed=args.seed)
    path, truth_path = write_installation(rec, args.out, base=args.base, force=args.force)
    print(f"wrote {path} ({args.kind}, {args.samples} samples, channels {', '.join(rec.channels)}) and {truth_path}")
    return 0


def run_runtime(args) -> int:
    from ..sim.runtime import simulate_runtime, write_runtime

    truth = _bench_truth(args)
    session = simulate_runtime(truth, args.samples, seed=args.seed, max_tilt_deg=args.max_tilt_deg,
                               accel_noise_g=None if args.no_accel else 0.002)
    rec, true_angles = write_runtime(session, args.out, force=args.force)
    print(f"wrote {rec} ({args.samples} samples, channels {', '.join(session.channels)}) and {true_angles}")
    return 0
