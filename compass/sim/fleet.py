"""A simulated production line: one bench, a lot of modules, a few bad ones, a drift.

Every module is a three-axis digital magnetometer (outputs in counts, zero at zero field, about
0.15 uT a count) drawn from one population: channels within ``misalign_deg`` of the housing axes,
gains within +-10 %, offsets of a few uT, noise 0.15 uT.  Each gets one four-flip session
(:func:`compass.sim.fourflip.simulate_fourflip`) on the same bench, one after another.

Named defects (:data:`DEFECTS`) go to a few modules; every one should fail acceptance:

- ``dead_channel``: one channel reads a constant plus 0.5 counts of noise (issue 27);
- ``noisy_channel``: one channel with 20 times the noise (a broken front end);
- ``misaligned_channel``: one channel mounted 20 deg off its housing axis;
- ``magnetised``: a magnetised part in the module: 250 uT of hard iron along one axis;
- ``weak_channel``: one channel's gain 40 % low;
- ``truncated``: the session stopped during the second flip (cannot be calibrated);
- ``corrupt``: a cell of the file is not a number (cannot be read).

The drift: from session ``drift_start`` on, the bench's field turns (a steel cabinet or a magnetised
tool moved closer to the turntable), so the dip every module measures moves by
``drift_deg_per_session`` a session.  No module fails for it; the line's control chart should flag it.

The truth (``fleet_truth.json``) lists every module, its file, session index and time, its defect,
whether it should fail, and where the drift starts.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ..io.atomic import atomic_write_text
from ._files import csv_text
from .fourflip import simulate_fourflip

__all__ = ["DEFECTS", "FleetOptions", "simulate_fleet"]

DEFECTS = ("dead_channel", "noisy_channel", "misaligned_channel", "magnetised", "weak_channel", "truncated", "corrupt")

COUNT_UT = 0.15
"""Field of one output count, uT (nominal: the gains vary by module)."""

_VOLTS_MID, _VOLTS_PER_UT = 2.5, 0.02  # the four-flip simulator's analog outputs, turned into counts


@dataclass(frozen=True)
class FleetOptions:
    """The line's population and schedule.

    Attributes
    ----------
    n : int
        Modules (one session each).
    seed : int
    defect_rate : float
        Fraction of modules with a defect (at least one of each defect when n allows).
    drift_start : int or None
        Session index where the bench's dip starts to move (default: two thirds of the way).
    drift_deg_per_session : float
    bench_dip_deg, field_ut : float
        The bench's field before the drift.
    step_deg : float
        Turntable step of every session (4 deg: 360 samples).
    noise_ut, misalign_deg : float
    session_minutes : float
        Time between sessions.
    """

    n: int = 200
    seed: int = 0
    defect_rate: float = 0.06
    drift_start: int | None = None
    drift_deg_per_session: float = 0.02
    bench_dip_deg: float = 64.0
    field_ut: float = 50.0
    step_deg: float = 4.0
    noise_ut: float = 0.15
    misalign_deg: float = 1.0
    session_minutes: float = 6.0


def _defects(options: FleetOptions, rng) -> list[str | None]:
    """One entry per session: a defect name or None (the first three sessions are clean)."""
    n = options.n
    count = max(len(DEFECTS), int(round(options.defect_rate * n))) if n >= 2 * len(DEFECTS) else max(1, n // 4)
    slots = rng.choice(np.arange(min(n, 3), n), size=min(count, max(n - 3, 0)), replace=False)
    out: list[str | None] = [None] * n
    for k, slot in enumerate(sorted(slots, key=lambda _: rng.random())):  # shuffled
        out[int(slot)] = DEFECTS[k % len(DEFECTS)]
    return out


def _directions(rng, misalign_deg: float, defect: str | None) -> np.ndarray:
    tilt = Rotation.from_rotvec(rng.normal(scale=np.radians(misalign_deg) / np.sqrt(2), size=(3, 3)))
    a = tilt.apply(np.eye(3))
    if defect == "misaligned_channel":
        c = int(rng.integers(3))
        axis = np.cross(a[c], rng.normal(size=3))
        a[c] = Rotation.from_rotvec(np.radians(20.0) * axis / np.linalg.norm(axis)).apply(a[c])
    return a


def simulate_module(options: FleetOptions, index: int, defect: str | None, dip_deg: float):
    """One module's session: ``(columns, table, formats, truth)``, the outputs in counts."""
    rng = np.random.default_rng([options.seed, index])
    directions = _directions(rng, options.misalign_deg, defect)
    session = simulate_fourflip(seed=int(rng.integers(2**31)), directions=directions, noise_ut=options.noise_ut,
                                field_ut=options.field_ut, dip_deg=dip_deg, step_deg=options.step_deg)
    counts_per_volt = 1.0 / (_VOLTS_PER_UT * COUNT_UT)
    counts = (session.outputs - _VOLTS_MID) * counts_per_volt
    truth_gains = np.asarray(session.truth["gains_per_ut"]) * counts_per_volt
    channel = int(rng.integers(3))
    detail: dict = {}
    if defect == "dead_channel":
        counts[:, channel] = rng.normal(12.0, 0.5, len(counts))
        detail = {"channel": session.channels[channel], "noise_counts": 0.5}
    elif defect == "noisy_channel":
        noise = options.noise_ut * truth_gains[channel]
        counts[:, channel] += rng.normal(scale=noise * np.sqrt(20.0**2 - 1.0), size=len(counts))
        detail = {"channel": session.channels[channel], "noise_factor": 20.0}
    elif defect == "magnetised":
        hard_iron_ut = np.zeros(3)
        hard_iron_ut[channel] = rng.choice([-1.0, 1.0]) * 250.0
        counts += (directions @ hard_iron_ut) * truth_gains
        detail = {"hard_iron_ut": hard_iron_ut.tolist()}
    elif defect == "weak_channel":
        mid = np.median(counts[:, channel])
        counts[:, channel] = mid + 0.6 * (counts[:, channel] - mid)
        detail = {"channel": session.channels[channel], "gain_factor": 0.6}
    elif defect == "misaligned_channel":
        detail = {"angle_deg": 20.0}
    s = session.samples
    columns = ["t_s", "flip_deg", "platform_deg", *session.channels]
    table = np.column_stack([s.t_s, s.flip_deg, s.platform_deg, counts])
    if defect == "truncated":
        table = table[: int(len(table) * 0.375)]  # one and a half flips of four
        detail = {"rows_kept": len(table)}
    truth = {"directions": directions.tolist(), "gains_per_ut": truth_gains.tolist(), "dip_deg": dip_deg,
             "defect_detail": detail}
    return columns, table, ["%.3f", "%.1f", "%.4f", "%.3f", "%.3f", "%.3f"], truth


def simulate_fleet(out_dir, options: FleetOptions = FleetOptions(), *, force: bool = False,
                   progress=None) -> dict:
    """Write ``options.n`` session recordings and ``fleet_truth.json`` into ``out_dir``.

    Returns
    -------
    dict
        The truth (also written).

    Raises
    ------
    FileExistsError
        A file to write exists and ``force`` is False (nothing is written then).
    """
    out_dir = Path(out_dir)
    names = [f"M{i + 1:04d}" for i in range(options.n)]
    paths = [out_dir / f"{name}.csv" for name in names]
    truth_path = out_dir / "fleet_truth.json"
    if not force:
        for p in [*paths, truth_path]:
            if p.exists():
                raise FileExistsError(f"{p} exists; use --force to overwrite")
    out_dir.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(options.seed)
    defects = _defects(options, rng)
    drift_start = options.drift_start if options.drift_start is not None else (2 * options.n) // 3
    t0 = datetime(2026, 3, 2, 7, 0, tzinfo=timezone.utc)
    modules = []
    for i, (name, path, defect) in enumerate(zip(names, paths, defects)):
        dip = options.bench_dip_deg + options.drift_deg_per_session * max(0, i - drift_start)
        columns, table, formats, truth = simulate_module(options, i, defect, dip)
        when = (t0 + timedelta(minutes=options.session_minutes * i)).isoformat(timespec="seconds")
        metadata = {"module_id": name, "date": when, "field_ut": f"{options.field_ut:g}", "operator": "simulated line",
                    "source": f"compass simulate fleet --seed {options.seed} (session {i})"}
        text = csv_text(columns, table, formats, metadata)
        if defect == "corrupt":
            lines = text.splitlines(keepends=True)
            row = len(metadata) + 1 + len(table) // 2
            cells = lines[row].split(",")
            cells[3] = "ERR"
            lines[row] = ",".join(cells) + ("" if cells[-1].endswith("\n") else "\n")
            text = "".join(lines)
            truth["defect_detail"] = {"line": row + 1, "column": columns[3]}
        atomic_write_text(path, text)
        modules.append({"module_id": name, "file": path.name, "session": i, "session_time": when, "defect": defect,
                        "should_fail": defect is not None, "bench_dip_deg": dip, **truth})
        if progress is not None and (i + 1) % 20 == 0:
            progress(f"{i + 1}/{options.n} sessions")
    truth = {"options": {k: getattr(options, k) for k in options.__dataclass_fields__},
             "drift": {"start_session": drift_start, "figure": "bench_dip_deg",
                       "deg_per_session": options.drift_deg_per_session,
                       "cause": "the bench's field turns (a steel cabinet moved closer to the turntable)"},
             "modules": modules}
    atomic_write_text(truth_path, json.dumps(truth, indent=1) + "\n")
    return truth
