"""``compass simulate fourflip``: write a simulated bench session and its truth."""

from __future__ import annotations

from ..sim.fourflip import SIM_EFFECTS, simulate_fourflip, write_fourflip


def register(sub) -> None:
    p = sub.add_parser("simulate", help="write simulated recordings (with their truth beside them)")
    kinds = p.add_subparsers(dest="kind", required=True, metavar="KIND")
    ff = kinds.add_parser("fourflip", help="a four-flip turntable session (seed 000)")
    ff.add_argument("--out", required=True, help="recording CSV to write; truth goes to <stem>.truth.json")
    ff.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    ff.add_argument("--channels", type=int, default=3, help="number of single-axis channels (default 3)")
    ff.add_argument("--effect", action="append", default=[], choices=SIM_EFFECTS,
                    help="inject an effect (repeatable); the truth file records its parameters")
    ff.add_argument("--noise-ut", type=float, default=0.15, help="white noise, uT (default 0.15)")
    ff.add_argument("--field-ut", type=float, default=50.0, help="|B|, uT (default 50)")
    ff.add_argument("--dip-deg", type=float, default=None, help="dip, deg (default: random 40..70)")
    ff.add_argument("--step-deg", type=float, default=1.0, help="turntable step, deg (default 1)")
    ff.add_argument("--effect-scale", type=float, default=1.0, help="multiply every effect size")
    ff.add_argument("--force", action="store_true", help="overwrite existing files")
    ff.set_defaults(func=run_fourflip)
    p3 = kinds.add_parser("platform3d", help="a 3-D platform session with a tilt sensor (seed 001)")
    p3.add_argument("--out", required=True, help="recording CSV to write; truth goes to <stem>.truth.json")
    p3.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p3.add_argument("--poses", choices=("grid", "random", "turntable"), default="grid",
                    help="platform poses (default grid; turntable never tilts and cannot be calibrated)")
    p3.add_argument("--tilt-axes", type=int, choices=(2, 3), default=2, help="tilt sensor axes (default 2)")
    p3.add_argument("--force", action="store_true", help="overwrite existing files")
    p3.set_defaults(func=run_platform3d)


def run_fourflip(args) -> int:
    from ..cli import BadInput

    if args.channels < 1:
        raise BadInput(f"--channels must be at least 1, got {args.channels}")
    if not 0 < args.step_deg <= 30:
        raise BadInput(f"--step-deg must be in (0, 30], got {args.step_deg}")
    if not args.noise_ut >= 0:
        raise BadInput(f"--noise-ut must not be negative, got {args.noise_ut}")
    if not args.field_ut > 0:
        raise BadInput(f"--field-ut must be positive, got {args.field_ut}")
    if args.dip_deg is not None and not -90 <= args.dip_deg <= 90:
        raise BadInput(f"--dip-deg must be in [-90, 90], got {args.dip_deg}")
    if not args.effect_scale >= 0:
        raise BadInput(f"--effect-scale must not be negative, got {args.effect_scale}")
    session = simulate_fourflip(
        seed=args.seed, n_channels=args.channels, effects=tuple(args.effect), noise_ut=args.noise_ut,
        field_ut=args.field_ut, dip_deg=args.dip_deg, step_deg=args.step_deg, effect_scale=args.effect_scale,
    )
    rec, truth = write_fourflip(session, args.out, force=args.force)
    print(f"wrote {rec} ({session.outputs.shape[0]} samples, {len(session.channels)} channels"
          f"{', effects: ' + ', '.join(args.effect) if args.effect else ''}) and {truth}")
    return 0


def run_platform3d(args) -> int:
    from ..sim.platform3d import simulate_platform3d, write_platform3d

    sim = simulate_platform3d(seed=args.seed, poses=args.poses, tilt_axes=args.tilt_axes)
    rec, truth = write_platform3d(sim, args.out, force=args.force)
    print(f"wrote {rec} ({len(sim.mag)} samples) and {truth}")
    return 0
