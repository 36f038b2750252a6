"""The fleet report: ``report.html`` (static, plots inline as PNG) and ``figures.csv``.

What a line's engineer reads after a batch: the yield over modules (each decided as
:func:`compass.production.store.module_outcome` says; duplicate module ids named), every judged
figure's distribution against its limit, the EWMA control chart of the spec's ``[control] figures``
over session time (a drifting line flagged at the session where it left its limits), and the worst
modules with their reasons.
``figures.csv`` has one row a session with every figure, for the user's own analysis.
"""

from __future__ import annotations

import base64
import csv
import html
import io
import math
from pathlib import Path

import numpy as np

from ..io.atomic import atomic_write_text
from .control import ewma_chart
from .figures import FIGURES
from .store import module_outcomes

__all__ = ["ControlResult", "control_results", "write_csv", "write_report"]

_WORST = 25
"""Failed modules listed in the report (the CSV has them all)."""


class ControlResult:
    """One control figure's chart over the calibrated sessions, or why there is none."""

    def __init__(self, figure: str, rows, positions, chart=None, why: str | None = None):
        self.figure, self.rows, self.positions, self.chart, self.why = figure, rows, positions, chart, why

    @property
    def alarm_session(self) -> int | None:
        """The session number (1-based, time order, refused sessions counted) of the first alarm, or None."""
        return None if self.alarm_row is None else self.positions[self.chart.first_alarm]

    @property
    def alarm_row(self):
        """The session where the chart first left its limits, or None."""
        return None if self.chart is None or self.chart.first_alarm is None else self.rows[self.chart.first_alarm]


def control_results(rows, spec) -> list[ControlResult]:
    """The EWMA chart of each of the spec's control figures over the calibrated sessions, in time order."""
    out = []
    for name in spec.control_figures:
        numbered = [(k, r) for k, r in enumerate(rows, 1) if r.status != "refused" and _finite(r.figures.get(name))]
        charted, positions = [r for _, r in numbered], [k for k, _ in numbered]
        try:
            chart = ewma_chart([r.figures[name] for r in charted], baseline=spec.baseline_sessions,
                               lam=spec.ewma_lambda, width_sigmas=spec.width_sigmas)
        except ValueError as exc:
            out.append(ControlResult(name, charted, positions, why=str(exc)))
            continue
        out.append(ControlResult(name, charted, positions, chart))
    return out


def _finite(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def write_csv(path, rows) -> Path:
    """One row a session: identity, verdict, every figure, the warning classes and the reasons."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(["module_id", "session_time", "status", "kind", *FIGURES, "unexplained", "warning_classes",
                     "reasons", "recording_path", "recording_sha256"])
    for r in rows:
        f = r.figures
        writer.writerow([r.module_id, r.session_time, r.status, r.kind or "",
                         *("" if f.get(n) is None else f"{f[n]:.6g}" for n in FIGURES),
                         "" if f.get("unexplained") is None else str(f["unexplained"]).lower(),
                         " ".join(f.get("warning_classes", [])), " | ".join(r.reasons), r.recording_path,
                         r.recording_sha256])
    atomic_write_text(path, buffer.getvalue())
    return Path(path)


def _png(fig) -> str:
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=90)
    import matplotlib.pyplot as plt

    plt.close(fig)
    return "data:image/png;base64," + base64.b64encode(buffer.getvalue()).decode()


def _distribution_png(name, rows, limits) -> str:
    import matplotlib.pyplot as plt

    unit = FIGURES[name].unit
    low, high = limits
    good = np.array([r.figures[name] for r in rows if r.status == "accepted" and _finite(r.figures.get(name))])
    bad = np.array([r.figures[name] for r in rows if r.status == "rejected" and _finite(r.figures.get(name))])
    fig, ax = plt.subplots(figsize=(4.6, 2.6), layout="constrained")
    values = np.concatenate([good, bad]) if len(good) + len(bad) else np.array([np.nan])
    marks = [v for v in (low, high) if v is not None]
    span = np.concatenate([values[np.isfinite(values)], marks])
    log = len(span) and np.all(span > 0) and span.max() / span.min() > 100
    if log:
        bins = np.geomspace(span.min() * 0.9, span.max() * 1.1, 40)
        ax.set_xscale("log")
    else:
        bins = np.linspace(span.min(), span.max(), 40) if len(span) and span.max() > span.min() else 20
    ax.hist([good, bad], bins=bins, stacked=True, color=["#4c9a2a", "#c0392b"], label=["accepted", "rejected"])
    for v, label in ((low, "min"), (high, "max")):
        if v is not None:
            ax.axvline(v, color="k", linestyle="--", linewidth=1.2)
            ax.annotate(f"{label} {v:g}", (v, 1.0), xycoords=("data", "axes fraction"), xytext=(3, -12),
                        textcoords="offset points", fontsize=8)
    ax.set_xlabel(f"{name} ({unit}){'  log scale' if log else ''}", fontsize=9)
    ax.set_ylabel("sessions", fontsize=9)
    ax.tick_params(labelsize=8)
    ax.legend(fontsize=7, loc="best")
    return _png(fig)


def _control_png(result: ControlResult) -> str:
    import matplotlib.pyplot as plt

    c = result.chart
    i = np.asarray(result.positions)
    unit = FIGURES[result.figure].unit
    fig, ax = plt.subplots(figsize=(11.0, 3.2), layout="constrained")
    spread = max(c.high.max() - c.centre, c.centre - c.low.min())
    lo, hi = np.percentile(c.values, [5, 95])
    bottom, top = min(lo, c.centre - 4 * spread), max(hi, c.centre + 4 * spread)
    margin = 0.08 * (top - bottom)
    bottom, top = bottom - margin, top + margin
    inside = (c.values >= bottom) & (c.values <= top)
    ax.plot(i[inside], c.values[inside], ".", color="#7f8c99", markersize=4, label="each session")
    for side, edge, marker in ((c.values > top, top, "^"), (c.values < bottom, bottom, "v")):
        if side.any():
            ax.plot(i[side], np.full(side.sum(), edge), marker, color="#7f8c99", markersize=5, clip_on=False,
                    label="off the scale")
    ax.plot(i, c.ewma, "-", color="#1f4e79", linewidth=1.6, label="EWMA (each value clipped at 3 sigma)")
    ax.plot(i, c.low, "--", color="#c0392b", linewidth=1)
    ax.plot(i, c.high, "--", color="#c0392b", linewidth=1, label="control limits")
    ax.axvspan(i[0] - 0.5, i[c.baseline - 1] + 0.5, color="#eef2f6", label=f"baseline ({c.baseline} sessions)")
    if c.first_alarm is not None:
        ax.axvline(i[c.first_alarm], color="#c0392b", linewidth=1.5)
        ax.plot(i[c.out], c.ewma[c.out], "o", color="#c0392b", markersize=3, label="out of control")
    ax.set_ylim(bottom, top)
    ax.set_xlabel("session number (time order)", fontsize=9)
    ax.set_ylabel(f"{result.figure} ({unit})", fontsize=9)
    ax.tick_params(labelsize=8)
    ax.legend(fontsize=7, ncol=6, loc="lower left", bbox_to_anchor=(0.0, 1.0), frameon=False)
    return _png(fig)


def _ratio_over_limit(value, limits) -> float:
    """How far past its limit a figure is (>1: failed), for ranking the worst modules."""
    low, high = limits
    worst = 0.0
    if _finite(value):
        if high is not None and high > 0:
            worst = max(worst, value / high)
        if low is not None and value > 0:
            worst = max(worst, low / value)
        elif low is not None:
            worst = math.inf
    return worst


def write_report(out_dir, rows, spec, *, spec_source: str, toolkit_version: str, title: str = "Fleet report",
                 rivals=()):
    """Write ``report.html`` and ``figures.csv`` into ``out_dir`` for these sessions (time order).

    ``rivals`` are the store's other recordings claiming a session of ``rows``
    (:meth:`compass.production.store.Store.rivals`): their modules count as duplicate ids, listed with every file; they
    are not sessions of the report.

    Returns
    -------
    (Path, Path, list of ControlResult)
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    csv_path = write_csv(out_dir / "figures.csv", rows)
    modules = module_outcomes(rows, rivals)
    counts = {s: sum(m.status == s for m in modules) for s in ("accepted", "rejected", "refused", "duplicate")}
    total = len(rows)
    controls = control_results(rows, spec)
    e = html.escape
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>{e(title)}</title><style>"
             "body{font-family:system-ui,sans-serif;margin:1.5em 2em;color:#222;max-width:1100px}"
             "h1{margin-bottom:0.2em}h2{margin-top:1.6em;border-bottom:1px solid #ccc}"
             "table{border-collapse:collapse;font-size:13px}td,th{border:1px solid #ddd;padding:3px 7px;"
             "text-align:left;vertical-align:top}th{background:#f3f5f7}.num{text-align:right}.when{white-space:nowrap}"
             ".ok{color:#2e7d32;font-weight:600}.bad{color:#c0392b;font-weight:600}"
             ".grid{display:flex;flex-wrap:wrap;gap:8px}.grid figure{margin:0}"
             ".note{color:#555;font-size:13px}.alarm{background:#fdecea;padding:6px 10px;border-left:4px solid #c0392b}"
             ".calm{background:#eaf5ea;padding:6px 10px;border-left:4px solid #2e7d32}</style></head><body>"]
    yield_pct = 100.0 * counts["accepted"] / len(modules) if modules else float("nan")
    times = [r.session_time for r in rows]
    parts.append(f"<h1>{e(title)}</h1><p class='note'>{total} sessions"
                 + (f" from {e(times[0])} to {e(times[-1])}" if times else "")
                 + f"; spec {e(spec_source)} (sha256 {spec.sha256[:12]}); compass {e(toolkit_version)}. "
                 "Every module's figures: <a href='figures.csv'>figures.csv</a>.</p>")
    parts.append(f"<h2>Yield</h2><p class='note'>{len(modules)} modules (module ids) in {total} sessions; a "
                 "module is decided by its latest session's verdict (a later rejection supersedes an "
                 "earlier acceptance).</p>"
                 "<table><tr><th>accepted</th><th>rejected (a limit failed)</th>"
                 "<th>refused (could not be calibrated)</th><th>duplicate id (different recordings, one "
                 "session time)</th><th>yield</th></tr>"
                 f"<tr><td class='num ok'>{counts['accepted']}</td><td class='num bad'>{counts['rejected']}</td>"
                 f"<td class='num bad'>{counts['refused']}</td><td class='num bad'>{counts['duplicate']}</td>"
                 f"<td class='num'><b>{yield_pct:.1f} %</b></td></tr></table>")
    duplicates = [m for m in modules if m.status == "duplicate"]
    if duplicates:
        parts.append("<p class='alarm'><b>Duplicate module ids</b>: different recordings claim one module's "
                     "session; none of them is accepted or exported until the wrong one is corrected and the "
                     "module recorded again.<br>"
                     + "<br>".join(f"{e(m.module_id)} at {e(m.row.session_time)}: "
                                   + ", ".join(e(r.recording_path) for r in sorted((m.row, *m.rivals),
                                                                                   key=lambda r: r.recording_path))
                                   for m in duplicates) + "</p>")
    parts.append("<h2>Is the line drifting?</h2><p class='note'>EWMA control charts over session time "
                 f"(lambda {spec.ewma_lambda:g}, limits {spec.width_sigmas:g} sigma from the first "
                 f"{spec.baseline_sessions} sessions; refused sessions left out; each value enters the average "
                 "clipped at 3 sigma, so one bad module cannot raise a flag). A flagged chart means the line "
                 "changed, not one module: a flag on the bench's dip points at the bench, one on a module "
                 "figure at the lot of parts.</p>")
    for c in controls:
        if c.chart is None:
            parts.append(f"<p class='note'><b>{e(c.figure)}</b>: no chart: {e(c.why)}</p>")
            continue
        row = c.alarm_row
        if row is None:
            parts.append(f"<p class='calm'><b>{e(c.figure)}</b>: in control over {len(c.rows)} sessions.</p>")
        else:
            parts.append(f"<p class='alarm'><b>{e(c.figure)}</b>: <b>drift flagged</b> at session "
                         f"{c.alarm_session} of {total} (module {e(row.module_id)}, {e(row.session_time)}): "
                         f"its average left the limits {c.chart.centre:.6g} +- "
                         f"{c.chart.high[-1] - c.chart.centre:.2g} {FIGURES[c.figure].unit}.</p>")
        parts.append(f"<img alt='EWMA chart of {e(c.figure)}' src='{_control_png(c)}'>")
    parts.append("<h2>Figures against their limits</h2>")
    shown = [(name, limits) for name, limits in spec.limits.items()
             if any(r.status in ("accepted", "rejected") and _finite(r.figures.get(name)) for r in rows)]
    if shown:
        parts.append("<p class='note'>Calibrated sessions only; the dashed line is the spec's limit. A figure the "
                     "calibration kind does not give is left out.</p><div class='grid'>")
        for name, limits in shown:
            parts.append(f"<figure><img alt='{e(name)}' src='{_distribution_png(name, rows, limits)}'>"
                         f"<figcaption class='note'>{e(FIGURES[name].meaning)}</figcaption></figure>")
        parts.append("</div>")
    else:
        parts.append("<p class='note'>No calibrated session gives a figure the spec judges: nothing to plot (every "
                     "session was refused; see the failed modules below).</p>")
    failed = [r for r in rows if r.status != "accepted"]
    failed.sort(key=lambda r: (r.status != "refused",
                               -max([_ratio_over_limit(r.figures.get(n), lim) for n, lim in spec.limits.items()]
                                    + [0.0]), r.session_time))
    parts.append(f"<h2>Failed modules ({len(failed)})</h2>")
    if failed:
        shown = failed[:_WORST]
        more = f" (the first {_WORST}: refused, then the farthest past a limit)" if len(failed) > _WORST else ""
        parts.append(f"<p class='note'>Refused first, then by how far a figure is past its limit{more}.</p>"
                     "<table><tr><th>module</th><th>session time</th><th>verdict</th><th>reasons</th></tr>")
        for r in shown:
            reasons = "<br>".join(e(x) for x in r.reasons)
            parts.append(f"<tr><td>{e(r.module_id)}</td><td class='when'>{e(r.session_time)}</td>"
                         f"<td class='bad'>{e(r.status)}</td><td>{reasons}</td></tr>")
        parts.append("</table>")
    else:
        parts.append("<p class='calm'>Every module was accepted.</p>")
    unjudged = [r for r in rows if r.notes]
    if unjudged:
        parts.append(f"<h2>Limits not judged ({len(unjudged)} sessions)</h2><p class='note'>A limit of the spec "
                     "these sessions' verdicts could not apply, and why ([missing] fail = true rejects them).</p>"
                     "<table><tr><th>module</th><th>session time</th><th>verdict</th><th>not judged</th></tr>")
        for r in unjudged:
            parts.append(f"<tr><td>{e(r.module_id)}</td><td class='when'>{e(r.session_time)}</td><td>{e(r.status)}"
                         f"</td><td>{'<br>'.join(e(x) for x in r.notes)}</td></tr>")
        parts.append("</table>")
    parts.append("</body></html>\n")
    html_path = out_dir / "report.html"
    atomic_write_text(html_path, "".join(parts))
    return html_path, csv_path, controls
