"""The offsets and gains a four-flip file states when the platform field is in the fit, against their real error.

    python tools/bench_platform_prior.py [--seeds 20] [--seed0 300] [--write-docs]

A field fixed to the turntable shows only its y part to the bench: its x part (along the flip axis) moves every
offset by ``gain a_x b_x`` and its z part (vertical) the gains' common scale and the dip
(:mod:`calibrate.fourflip._unseen`).  Before issue 24 both were read as zero (the file's sigmas the fit's alone);
now each takes the prior ``p_y^2 + s_y^2``.  Recordings from :func:`compass.sim.fourflip.simulate_fourflip` with
``platform_field`` (its draw: each component of the field an independent size, uniform in 0.3-0.6 uT times
the scale, random sign; the prior was chosen before reading it), at the simulator's scale and two others,
calibrated with the diagnosis; printed per setting: how often the loop named the platform field, the RMS over
channels and seeds of each offset's and gain's error over its stated sigma (1 = honest) before (the fit's
own sigma: the file's less the prior's part, ``diagnosis.platform_field_unseen``) and now, and the median
stated heading cost of the unseen parts (deg), all in the same run.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from calibrate import calibrate_fourflip  # noqa: E402
from compass.io.fourflip import read_fourflip  # noqa: E402
from compass.sim.fourflip import simulate_fourflip, write_fourflip  # noqa: E402
from tools._doc_table import markdown_table, parse_args, publish  # noqa: E402

SCALES = (1.0, 0.5, 2.0)


def _errors(result, truth) -> tuple[np.ndarray, ...]:
    """Offset and gain errors over the stated sigma, now and before the prior, per channel."""
    unseen = result.diagnosis["platform_field_unseen"]
    off_err = np.array([c.response.offset for c in result.channels]) - np.asarray(truth["offsets"])
    gain_err = np.array([c.response.gain for c in result.channels]) - np.asarray(truth["gains_per_ut"])
    off_sig = np.array([c.offset_sigma for c in result.channels])
    gain_sig = np.array([c.gain_sigma for c in result.channels])
    added = np.array([unseen["offset_sigma_added"][c.name] for c in result.channels])
    off_naive = np.sqrt(np.maximum(off_sig**2 - added**2, 0.0))
    return off_err / off_naive, off_err / off_sig, gain_err / gain_sig


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--seed0", type=int, default=300)
    args = parse_args(parser, argv)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for scale in SCALES:
            named, off_before, off_now, gain_now, cost = 0, [], [], [], []
            for seed in range(args.seed0, args.seed0 + args.seeds):
                session = simulate_fourflip(seed=seed, effects=("platform_field",), effect_scale=scale)
                path, _ = write_fourflip(session, Path(tmp) / f"r{scale:g}_{seed}.csv")
                result = calibrate_fourflip(read_fourflip(path), diagnose=True)
                if "platform_field_unseen" not in result.diagnosis:
                    continue
                named += 1
                if not result.diagnosis["platform_field_unseen"]["prior_stated"]:  # said in the warnings; no sigma
                    print(f"  scale {scale:g} seed {seed}: named, its y part undetermined: no prior stated",
                          file=sys.stderr)
                    continue
                before, now, gain = _errors(result, session.truth)
                off_before.append(before)
                off_now.append(now)
                gain_now.append(gain)
                cost.append(result.diagnosis["platform_field_unseen"]["heading_deg"])
                print(f"  scale {scale:g} seed {seed}: offset e/s {np.round(now, 2)}, gain e/s {np.round(gain, 2)}",
                      file=sys.stderr)
            rms = lambda v: float(np.sqrt(np.mean(np.square(v)))) if v else float("nan")  # noqa: E731
            rows.append([f"{scale:g}", f"{named}/{args.seeds}", f"{rms(off_before):.2f}", f"{rms(off_now):.2f}",
                         f"{rms(gain_now):.2f}", f"{np.median(cost):.3f}" if cost else "-"])
    header = ["platform scale", "named", "offset e/s before", "offset e/s now", "gain e/s now", "hdg cost deg"]
    print(f"bench_platform_prior: {args.seeds} seeds from {args.seed0} per scale (compass.sim.fourflip's draw)\n")
    publish(args, "docs/benchmarks.md", "bench_platform_prior", markdown_table(header, rows),
            caption="e/s: RMS over channels and seeds of the error over the file's sigma (1: honest); before: the "
                    "fit's own sigma (the file's less the prior's part); hdg cost: median "
                    "diagnosis.platform_field_unseen.heading_deg")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
