"""One recording of :mod:`bench_loop`: what its level heading error is made of, and whether it is bias or noise.

A level housing at the angle ``psi`` counter-clockwise from magnetic north (SPEC's heading ``-psi``) sees
``B = (H cos psi, -H sin psi, -Z)`` (``H = |B| cos D``, ``Z = |B| sin D``, ``D`` the dip).  To first order in each
parameter's error (``do`` the offset's in field units, ``e`` the gain's relative error, ``da`` the sensing
direction's, channels a and b nearly along housing X and Y), the angle read through the calibration is off by

.. math::

    \\delta\\psi = \\frac{do_a \\sin\\psi + do_b \\cos\\psi}{H}
        - \\tan D \\, (da_{a,z} \\sin\\psi + da_{b,z} \\cos\\psi)
        + \\tfrac12 (e_a - e_b) \\sin 2\\psi + da_{b,x} \\cos^2\\psi - da_{a,y} \\sin^2\\psi

(rad): the offsets over ``H`` and the horizontal channels' vertical tilts times ``tan D`` are the first harmonic,
both growing with the dip; the gains and the in-plane directions the second; a cubic left linear adds a fourth
(docs/benchmarks.md, "Four stacked, recording by recording").

Printed, for ``--case`` and ``--seed`` (this tree): each channel's offset, gain and direction error against the
truth the bench scores with (:class:`bench_loop.Truth`), with their sigmas; the heading error's harmonics 0-4 (deg)
as the calibration gives it, with each group of parameters put to the truth, and the expansion's terms; the same for a
fit with the TRUE effect set forced in (``--true``, in the order given: each refitted from the previous, no
evidence asked); then ``--draws`` fresh noise draws on the same truth (the recording at ``noise_ut`` 0 plus white
noise of ``bench_loop.NOISE_UT``, seeded ``1000 + seed``), and one at a hundredth of it (the bias): the loop's and the
forced set's heading err/sig and direction err/sig, RMS over the draws.

Run: ``python tools/bench_loop_heading.py [--case "four stacked"] [--seed 68] [--draws 12]
[--true gain_drift:degree 1,offset_drift:warm-up exponential,encoder_error:,nonlinear_response:powers 3]``.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse
import sys
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_loop as bl  # noqa: E402

FOUR_STACKED = "gain_drift:degree 1,offset_drift:warm-up exponential,encoder_error:,nonlinear_response:powers 3"
"""The effects ``four stacked`` is made of, as ``name:form`` (the loop's usual order of adding them)."""


@contextmanager
def forced_effects(forms: list[tuple[str, str]]):
    """Within the block, the four-flip diagnosis fits exactly ``forms`` (``(name, form)``, in order) instead of
    selecting: each is added to the previous fit from its score test's start and refitted; the verdict is asked of
    the last (what a fit with the true effect set gives)."""
    import calibrate.fourflip.diagnosis as diagnosis
    from calibrate.diagnosis.evidence import Selection

    def select(base, pool, *, score, refit, verdict, base_step, **_):
        current = base
        for name, form in forms:
            effect = next(e for e in pool if e.name == name and e.form == form)
            current = refit(current, effect, score(current, effect)[1])
        structure, unexplained = verdict(current)
        return Selection(current, [base_step], [], structure, unexplained, [])

    real = diagnosis.select_effects
    diagnosis.select_effects = select
    try:
        yield
    finally:
        diagnosis.select_effects = real


def harmonics_deg(error: np.ndarray) -> np.ndarray:
    """Amplitudes of harmonics 0-4 of an error sampled at equal steps over a turn, deg."""
    amplitude = 2.0 * np.abs(np.fft.rfft(error)) / error.size
    amplitude[0] /= 2.0
    return np.degrees(amplitude[:5])


def expansion(result, truth: bl.Truth, psi: np.ndarray) -> dict:
    """The module docstring's first-order terms of the heading error at ``psi`` from ``result``'s errors, rad."""
    level = truth.output(np.zeros((1, 3)))[0]
    do = (np.array([c.response.offset for c in result.channels]) - level) / truth.gains  # uT
    e = np.array([c.response.gain for c in result.channels]) / truth.gains - 1.0
    da = result.directions / np.linalg.norm(result.directions, axis=1, keepdims=True) - truth.directions
    dip = np.radians(truth.dip_deg)
    h = bl.FIELD_UT * np.cos(dip)
    return {"offsets / H": (do[0] * np.sin(psi) + do[1] * np.cos(psi)) / h,
            "tilts * tan D": -np.tan(dip) * (da[0, 2] * np.sin(psi) + da[1, 2] * np.cos(psi)),
            "gains": 0.5 * (e[0] - e[1]) * np.sin(2 * psi),
            "in-plane dirs": da[1, 0] * np.cos(psi) ** 2 - da[0, 1] * np.sin(psi) ** 2}


def describe(label: str, case: str, seed: int, result, truth: bl.Truth) -> None:
    """Print one calibration's parameter errors and its heading error's parts."""
    plain = bl.summarise(case, seed, truth, result, 0.0, 0.0)
    row = bl.with_heading_sigma(plain)
    without_curve = bl.with_heading_sigma(dict(plain, curve_covariance=None))["heading_sigma_deg"]
    level = truth.output(np.zeros((1, 3)))[0]
    print(f"\n{label}: effects {', '.join(result.diagnosis['effects']) or 'none'}; "
          f"unexplained {result.diagnosis['unexplained']}; heading err {row['heading_err_deg']:.3f} deg, "
          f"sigma {row['heading_sigma_deg']:.3f} ({without_curve:.3f} without the curve's covariance), "
          f"err/sig {row['heading_err_deg'] / row['heading_sigma_deg']:.2f}")
    da = result.directions / np.linalg.norm(result.directions, axis=1, keepdims=True) - truth.directions
    for i, c in enumerate(result.channels):
        do = c.response.offset - level[i]
        dg = c.response.gain - truth.gains[i]
        print(f"  {c.name}: offset {do / truth.gains[i]:+.4f} uT ({do / c.offset_sigma:+.2f} sig), gain "
              f"{dg / truth.gains[i]:+.5f} +- {c.gain_sigma / truth.gains[i]:.5f} ({dg / c.gain_sigma:+.1f} sig), "
              f"direction {row['err_deg'][i]:.4f} deg "
              f"({row['ratio'][i]:.2f} sig; dx, dy, dz {', '.join(f'{v:+.1e}' for v in da[i])})")
    psi = np.linspace(0.0, 2 * np.pi, bl.N_HEADINGS, endpoint=False)
    fitted = [c.response for c in result.channels]
    true_offsets = [replace(r, offset=level[i]) for i, r in enumerate(fitted)]
    true_gains = [replace(r, gain=truth.gains[i]) for i, r in enumerate(fitted)]
    parts = {"as calibrated": bl.level_heading_errors(fitted, result.directions, truth, psi),
             "true offsets": bl.level_heading_errors(true_offsets, result.directions, truth, psi),
             "true gains": bl.level_heading_errors(true_gains, result.directions, truth, psi),
             "true directions": bl.level_heading_errors(fitted, truth.directions, truth, psi),
             "true offsets, directions": bl.level_heading_errors(true_offsets, truth.directions, truth, psi)}
    terms = expansion(result, truth, psi)
    parts |= {f"expansion: {k}": v for k, v in terms.items()}
    parts["expansion: sum"] = sum(terms.values())
    print(f"  {'heading error (deg)':<34}{'rms':>7}   harmonics 0, 1, 2, 3, 4")
    for name, error in parts.items():
        print(f"  {name:<34}{np.degrees(np.sqrt(np.mean(error**2))):>7.4f}   "
              + ", ".join(f"{v:.4f}" for v in harmonics_deg(error)))


def draws(case: str, seed: int, n: int, forms: list[tuple[str, str]]) -> None:
    """Fresh noise on the same truth: the loop's and the forced set's heading and direction err/sig."""
    from calibrate import calibrate_fourflip

    quiet, truth = bl.session(seed, case, noise_ut=0.0)
    rng = np.random.default_rng(1000 + seed)
    print(f"\nfresh noise draws on seed {seed}'s truth (rng {1000 + seed}): heading err/sig, direction err/sig (RMS)")
    settings = (("a hundredth of the noise", bl.NOISE_UT / 100, 1), ("the bench's noise", bl.NOISE_UT, n))
    for label, scale, count in settings:
        ratios = {"loop": [], "true set": []}
        for _ in range(count):
            out = quiet.outputs + rng.normal(size=quiet.outputs.shape) * truth.gains * scale
            rec = replace(quiet, outputs=out)
            for name in ratios:
                if name == "loop":
                    result = calibrate_fourflip(rec, diagnose=True)
                else:
                    with forced_effects(forms):
                        result = calibrate_fourflip(rec, diagnose=True)
                row = bl.with_heading_sigma(bl.summarise(case, seed, truth, result, 0.0, 0.0))
                ratios[name].append((row["heading_err_deg"] / row["heading_sigma_deg"], row["ratio"],
                                     row["heading_err_deg"], "nonlinear_response" in result.diagnosis["effects"]))
        for name, rows in ratios.items():
            heading = np.sqrt(np.mean([r[0] ** 2 for r in rows]))
            direction = np.sqrt(np.mean(np.concatenate([r[1] for r in rows]) ** 2))
            print(f"  {label} ({count}), {name}: heading err/sig {heading:.2f}, direction err/sig {direction:.2f}, "
                  f"heading err RMS {np.sqrt(np.mean([r[2] ** 2 for r in rows])):.4f} deg, "
                  f"cubic named {sum(r[3] for r in rows)}/{count}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", default="four stacked", choices=bl.CASES)
    parser.add_argument("--seed", type=int, default=68)
    parser.add_argument("--draws", type=int, default=12, help="fresh noise draws on the same truth (0: none)")
    parser.add_argument("--true", default=FOUR_STACKED,
                        help="the true effect set, comma-separated name:form (default: four stacked's)")
    args = parser.parse_args()
    from calibrate import calibrate_fourflip

    forms = [tuple(item.split(":", 1)) for item in args.true.split(",")]
    rec, truth = bl.session(args.seed, args.case)
    print(f"bench_loop_heading: {args.case}, seed {args.seed}, dip {truth.dip_deg:.1f} deg, "
          f"H {bl.FIELD_UT * np.cos(np.radians(truth.dip_deg)):.1f} uT, tan D {np.tan(np.radians(truth.dip_deg)):.2f}")
    describe("the loop", args.case, args.seed, calibrate_fourflip(rec, diagnose=True), truth)
    with forced_effects(forms):
        forced = calibrate_fourflip(rec, diagnose=True)
    describe("the true effect set", args.case, args.seed, forced, truth)
    if args.draws:
        draws(args.case, args.seed, args.draws, forms)


if __name__ == "__main__":
    main()
