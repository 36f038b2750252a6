"""A stream without a clock, dated on arrival: the attitude each way of dating gives (issue 22, item 1).

Run: ``python tools/bench_clock.py [--seeds 2] [--rate 100]`` (about 3 min on a loaded 2-core machine).

A module that sends no ``t_s`` (the PJRC and Adafruit calibration sketches' ``Raw:`` lines, bare numbers) is
dated by the host from when its bytes arrive.  Each of :func:`compass.sim.motion.simulate_motion`'s kinds (60 s
at ``--rate``, :func:`bench_broad.board_errors`' two boards, seeds 0..) is sent in real time and read in
chunks as one of :data:`ARRIVALS` says; every sample of a chunk arrives at once.  Its samples are dated four
ways and run through the toolkit's pipeline (:func:`bench_broad.ours`: hard-iron tracker and filter), scored
as BROAD scores (heading / inclination RMS over the moving samples, deg):

- "true": the module's own times (the best any dating can do);
- "arrival": each sample at its chunk's arrival (``compass live`` before :class:`compass.io.clock.SampleClock`);
- "receive clock": the last sample of a chunk at its arrival, the others one period (the last 5 s' mean)
  before it (the bench station's clock before);
- "sample clock": :class:`compass.io.clock.SampleClock` (both now), fed run by run as ``compass live`` feeds it
  (with "1 % of lines broken", the lines lost before each sample, as the decoder tells ``compass live`` of the broken
  lines it dropped; "1 % of lines lost" loses them without a trace).

The dating error (the dated time less the true, less their median, after the first 2 s) is printed per
arrival model, with the widest step each dating gives where the module paused, and the samples a dating left
unsolved (a date earlier than the one before: the filter skips it; scored over the rest).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

from bench_broad import _Simulated, board_errors, ours_track  # noqa: E402

WIRE_S = 0.001
"""A line's time on the wire, s."""
PAUSE_AT_S, PAUSE_S = 30.0, 0.4
"""Where and how long the module pauses in the arrival model "module paused 0.4 s" (under the filter's 0.5 s gap), s."""


def busy_host(t_send: np.ndarray, rng) -> np.ndarray:
    """Arrival of each sample: the host reads every 1-20 ms, and 1 % of its reads come after a 50-200 ms stall."""
    gaps = rng.uniform(0.001, 0.020, int(2 * (t_send[-1] - t_send[0]) / 0.001) + 10)
    stalls = rng.random(len(gaps)) < 0.01
    gaps[stalls] = rng.uniform(0.05, 0.2, int(stalls.sum()))
    reads = t_send[0] + np.cumsum(gaps)
    return reads[np.searchsorted(reads, t_send + WIRE_S)]


def usb_adapter(t_send: np.ndarray, rng) -> np.ndarray:
    """An FTDI-style USB adapter: what arrived is sent every 16 ms (its latency timer), read 0-2 ms later."""
    flush = np.ceil((t_send + WIRE_S) / 0.016) * 0.016
    return flush + rng.uniform(0.0, 0.002, len(flush))[np.unique(flush, return_inverse=True)[1]]


def module_paused(t_send: np.ndarray, rng) -> np.ndarray:
    """A busy host, and the module sends nothing for :data:`PAUSE_S` from :data:`PAUSE_AT_S` (the samples then are
    not sent: dropped from the recording by :func:`kept`)."""
    return busy_host(t_send, rng)


def lines_lost(t_send: np.ndarray, rng) -> np.ndarray:
    """A busy host, and 1 % of the lines lost on the way (dropped from the recording by :func:`kept`)."""
    return busy_host(t_send, rng)


def wifi_bridge(t_send: np.ndarray, rng) -> np.ndarray:
    """A serial-to-WiFi bridge read over ``socket://``: it sends what it holds every 10 ms, each segment taking 3 ms plus
    an exponential 8 ms (in order), read 0-0.5 ms after it comes, all that has come: the delay varies before the host's
    buffer, so a sample missing from one read may have been sent before it."""
    form = np.ceil((t_send + WIRE_S) / 0.010) * 0.010
    packets = np.unique(form)
    comes = np.maximum.accumulate(packets + 0.003 + rng.exponential(0.008, len(packets)))
    read, i, last = np.empty(len(packets)), 0, -np.inf
    while i < len(packets):
        last = max(last, comes[i]) + rng.uniform(0.0, 0.0005)
        j = int(np.searchsorted(comes, last, side="right"))
        read[i:j], i = last, j
    return read[np.searchsorted(packets, form)]


def paced_by_delay(t_send: np.ndarray, rng) -> np.ndarray:
    """A busy host, and a module that waits one period after each sample's work (an Arduino ``delay()`` loop): its
    samples are sent :data:`WORK_SHARE` of a period apart more or less at random (chosen by :func:`kept`)."""
    return busy_host(t_send, rng)


ARRIVALS = {"busy host": busy_host, "USB adapter 16 ms": usb_adapter, "module paused 0.4 s": module_paused,
            "1 % of lines lost": lines_lost, "1 % of lines broken": lines_lost, "paced by delay()": paced_by_delay,
            "WiFi bridge": wifi_bridge}
BROKEN = "1 % of lines broken"
"""The arrival model whose lost lines leave a broken line the decoder counts (``compass live`` tells the clock)."""


WORK_SHARE = 0.15
"""The module paced by ``delay()``: each loop's work takes 0 to this share of a period on top of the delay."""
PACED_OVERSAMPLE = 10
"""The paced module's samples are picked from a simulation this many times the rate (their send times on its grid)."""


def kept(t_send: np.ndarray, arrival: str, seed: int) -> np.ndarray:
    """The samples that reach the host under ``arrival`` (for "paced by delay()", ``t_send`` is the simulation's fine
    grid, :data:`PACED_OVERSAMPLE` times the rate: the samples the module sends)."""
    if arrival == "paced by delay()":
        step = PACED_OVERSAMPLE * (1.0 + np.random.default_rng(3000 + seed).uniform(0.0, WORK_SHARE, len(t_send)))
        picks = np.round(np.cumsum(step)).astype(int)
        keep = np.zeros(len(t_send), bool)
        keep[picks[picks < len(t_send)]] = True
        return keep
    if arrival == "module paused 0.4 s":
        return (t_send < PAUSE_AT_S) | (t_send >= PAUSE_AT_S + PAUSE_S)
    if arrival in ("1 % of lines lost", BROKEN):
        return np.random.default_rng(2000 + seed).random(len(t_send)) >= 0.01
    return np.ones(len(t_send), bool)


def chunk_runs(t_rx: np.ndarray) -> list[tuple[int, int]]:
    """``(start, stop)`` of each run of samples that arrived together."""
    edges = np.flatnonzero(np.diff(t_rx) != 0.0) + 1
    bounds = np.concatenate([[0], edges, [len(t_rx)]])
    return list(zip(bounds[:-1].tolist(), bounds[1:].tolist()))


def dated(t_rx: np.ndarray, clock, lost: np.ndarray | None = None) -> np.ndarray:
    """Each run's samples dated by ``clock.date(m, t_rx)``; ``lost``: samples known lost before each sample (as the
    decoder tells ``compass live`` of a broken line: ``Sample.lost_before``)."""
    out = np.empty_like(t_rx)
    for start, stop in chunk_runs(t_rx):
        known = {} if lost is None else {"lost": lost[start:stop]}
        out[start:stop] = clock.date(stop - start, float(t_rx[start]), **known)
    return out


class ReceiveClock:
    """The bench station's clock before :class:`compass.io.clock.SampleClock` (to 7750442): a chunk's last
    sample at its arrival, the others one period apart before it, the period over the last 5 s of chunks."""

    def __init__(self, window_s: float = 5.0):
        self.window_s, self._received, self._count = window_s, [], 0

    def date(self, m: int, t_rx: float) -> np.ndarray:
        first = self._received[0] if self._received else None
        self._count += m
        self._received.append((t_rx, self._count))
        while len(self._received) > 2 and t_rx - self._received[1][0] >= self.window_s:
            self._received.pop(0)
        if first is None or t_rx <= self._received[0][0]:
            return np.full(m, float(t_rx))
        t0, n0 = self._received[0]
        period = (t_rx - t0) / (self._count - n0)
        return t_rx - period * np.arange(m - 1, -1, -1, dtype=float)


def datings(t_true: np.ndarray, t_rx: np.ndarray, lost: np.ndarray | None) -> tuple[dict[str, np.ndarray], int]:
    """The four datings of one stream, seconds (``lost``: see :func:`dated`; the sample clock's only), and the lines
    the sample clock counted lost without a trace (``SampleClock.lost_unseen``, what ``compass live``'s summary
    says)."""
    from compass.io.clock import SampleClock

    clock = SampleClock()
    times = {"true": t_true, "arrival": t_rx, "receive clock": dated(t_rx, ReceiveClock()),
             "sample clock": dated(t_rx, clock, lost)}
    return times, clock.lost_unseen


def dating_error_ms(t: np.ndarray, t_true: np.ndarray) -> np.ndarray:
    """|dated - true - median|, ms, after the first 2 s."""
    e = (t - t_true)[t_true >= t_true[0] + 2.0]
    return 1e3 * np.abs(e - np.median(e))


def solved_attitude(trial) -> tuple[np.ndarray, np.ndarray]:
    """:func:`bench_broad.ours`' attitude (``R_ENU<-body``, scalar first; identity where unsolved) and the rows
    solved (a time earlier than the one before is skipped by the filter: no attitude there)."""
    from compass.io.broad import nwu_to_enu

    quat = np.asarray(ours_track(trial).quat)
    solved = np.linalg.norm(quat, axis=1) > 0.5
    quat = np.where(solved[:, None], quat, [0.0, 0.0, 0.0, 1.0])
    return nwu_to_enu(Rotation.from_quat(quat)).as_quat(scalar_first=True), solved


def run(seeds: int, rate_hz: float, arrivals) -> None:
    from compass.evaluation import error_series
    from compass.sim.motion import KINDS, simulate_motion

    names = ("true", "arrival", "receive clock", "sample clock")
    print("heading / inclination RMS over the moving samples, deg, mean over the kinds and seeds "
          f"({', '.join(KINDS)}; seeds 0-{seeds - 1}; {rate_hz:g} Hz)")
    print(f"{'arrival model, board':38s} " + " ".join(f"{n:>15s}" for n in names))
    for arrival in arrivals:
        model = ARRIVALS[arrival]
        errors = {n: [] for n in names}
        unsolved = dict.fromkeys(names, 0)
        gaps, counted = [], [0, 0]  # lines lost without a trace, broad-like: (truly, counted by the sample clock)
        for board in ("broad-like", "low-cost"):
            cells = []
            for kind in KINDS:
                for seed in range(seeds):
                    fine = PACED_OVERSAMPLE if arrival == "paced by delay()" else 1
                    board_error = board_errors(board, seed)  # the gyro's per-sample noise as at the module's rate:
                    board_error = replace(board_error, gyro_noise=board_error.gyro_noise / np.sqrt(fine))  # picked
                    rec = simulate_motion(kind, seed=seed, rate_hz=fine * rate_hz, errors=board_error)
                    keep = kept(rec.t_s, arrival, seed)
                    t_rx = model(rec.t_s[keep], np.random.default_rng(seed))
                    trial = _Simulated(rec, kind)
                    for name in ("t_s", "gyro_rad_s", "accel_m_s2", "mag_ut", "movement", "ref_quat_enu"):
                        setattr(trial, name, getattr(trial, name)[keep])
                    trial.rate_hz = (len(trial.t_s) - 1) / (trial.t_s[-1] - trial.t_s[0])
                    row, t_true = [], trial.t_s
                    lost = np.diff(np.flatnonzero(keep), prepend=-1) - 1 if arrival == BROKEN else None
                    times, unseen = datings(t_true, t_rx, lost)
                    if board == "broad-like" and lost is None:
                        counted[0] += int(np.count_nonzero(~keep)) if arrival == "1 % of lines lost" else 0
                        counted[1] += unseen
                    for name, t in times.items():
                        if board == "broad-like":
                            errors[name].append(dating_error_ms(t, t_true))
                            if arrival == "module paused 0.4 s":
                                gaps.append((name, float(np.max(np.diff(t)))))
                        trial.t_s = t
                        quat, solved = solved_attitude(trial)
                        unsolved[name] += int(np.sum(~solved))
                        e = error_series(quat, trial.ref_quat_enu, trial.movement & solved, trial.rate_hz)
                        row.append((e.heading_rms_deg, e.inclination_rms_deg))
                    cells.append(row)
            mean = np.mean(cells, axis=0)
            print(f"{arrival + ', ' + board:38s} " + " ".join(f"{h:6.2f} / {i:5.2f}".rjust(15) for h, i in mean),
                  flush=True)
        print(f"{'  dating error p50 / p99 / max, ms':38s} " + " ".join(
            "{:.2f}/{:.1f}/{:.1f}".format(*np.percentile(np.concatenate(errors[n]), [50, 99, 100])).rjust(15)
            for n in names))
        if any(unsolved.values()):
            print(f"{'  samples unsolved (a date went back)':38s} " + " ".join(f"{unsolved[n]:15d}" for n in names))
        if any(counted):
            print(f"{'  lost without a trace / counted':38s} {counted[0]:d} / {counted[1]:d} (sample clock, broad-like)")
        if gaps:
            widest = {n: np.mean([g for m, g in gaps if m == n]) for n in names}
            print(f"{'  widest step dated (the pause), s':38s} " + " ".join(f"{widest[n]:15.3f}" for n in names))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=2, help="motion seeds per kind (default 2)")
    p.add_argument("--rate", type=float, default=100.0, help="the module's sample rate, Hz (default 100)")
    p.add_argument("--arrival", choices=tuple(ARRIVALS), action="append",
                   help="only this arrival model (repeatable; default: all)")
    args = p.parse_args(argv)
    run(args.seeds, args.rate, args.arrival or tuple(ARRIVALS))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
