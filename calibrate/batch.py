"""Production: calibrate many recordings, judge each against a spec, keep every verdict in the store.

:func:`calibrate_session` is one session, start to end, in whatever process runs it (a worker of a
local process pool, a Dask worker, or the caller): it reads the recording, calibrates it through
the same path as ``compass calibrate`` (:mod:`calibrate.session`, diagnosis on), and computes the
module's figures (:func:`compass.production.figures.module_figures`).  It never raises for a bad
recording: a recording that cannot be calibrated comes back ``refused`` with the reason.

:func:`run_batch` hands the sessions not yet stored to an executor and, in the calling process
only, judges each outcome as it arrives and stores it in its own transaction: a batch killed at any
moment keeps every session it finished and no half of one, and its re-run skips them.

A module id with one session time is one bench session: when different recordings (different
hashes, in this run or in the store) claim the same id and time, no one can tell which is the
module's (a copied header, a mistyped id).  The store is looked at before the run and again in each
session's transaction, under the store's write lock, so a rival another batch stored meanwhile is
caught too.  Each such session is stored ``rejected`` (``refused``
if it could not be calibrated) with the words naming every recording, so none of them is accepted
or exported; :attr:`BatchSummary.duplicates` lists them.  The same recording given again is one
session, never a duplicate.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
import warnings
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable

__all__ = ["BatchSummary", "SessionJob", "bench_field_ut", "calibrate_session", "duplicate_reason", "executor_outcomes",
           "run_batch", "session_identity", "shared_identities"]

_METADATA_LINES = 200
"""Comment lines read for ``module_id`` and ``date`` when the recording itself cannot be read."""


@dataclass(frozen=True)
class SessionJob:
    """What a worker needs for one session (picklable, small)."""

    path: str
    sha256: str
    site_dip_deg: float
    site_field_ut: float
    bench_field_ut: float | None = None


def sha256_of(path) -> str:
    """Hex SHA-256 of a file's bytes (what makes two sessions the same recording)."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def _header_metadata(path) -> dict:
    """``# key: value`` lines of a recording that may not read as a table (bytes decoded leniently)."""
    out = {}
    try:
        with open(path, encoding="utf-8", errors="replace") as f:
            for _, line in zip(range(_METADATA_LINES), f):
                stripped = line.strip()
                if stripped.startswith("#"):
                    key, sep, value = stripped[1:].partition(":")
                    if sep and key.strip():
                        out[key.strip()] = value.strip()
    except OSError:
        pass
    return out


def session_identity(path) -> tuple[str, str]:
    """A recording's module id (``# module_id:``, else the file name) and session time (:func:`_session_time`)."""
    metadata = _header_metadata(path)
    return metadata.get("module_id") or Path(path).stem, _session_time(path, metadata)


def _session_time(path, metadata: dict) -> str:
    """The session's time: ``# session_time:`` or ``# date:`` as its UTC instant or day
    (:func:`compass.production.store.session_time_text`), else the file's mtime (UTC, ISO).

    Raises
    ------
    SessionTimeError
        The recording's time is neither form (the message names the file and the key).
    """
    from compass.production.store import SessionTimeError, session_time_text

    for key in ("session_time", "date"):
        if metadata.get(key):
            try:
                return session_time_text(metadata[key])
            except SessionTimeError as exc:
                raise SessionTimeError(f"{path}: '# {key}:' {exc}") from None
    try:
        return datetime.fromtimestamp(os.path.getmtime(path), timezone.utc).isoformat(timespec="seconds")
    except OSError:
        return ""


def bench_field_ut(document: dict, spec_bench_field_ut: float | None) -> float | None:
    """The bench's |B| in uT for a calibration without ``# field_ut:`` (its field unit is the bench's |B|).

    The World Magnetic Model's |B| the calibration's site check compared with (its ``site_check``: the recording's
    ``# site_lat_deg:``, ``# site_lon_deg:``, ``# site_alt_m:`` and ``# date:``, what ``compass bench --site``
    writes; :func:`calibrate.site_field.compare_with_site`), else the spec's ``[site] bench_field_ut``, else None
    (the offset cannot be put in uT).
    """
    return (document.get("site_check") or {}).get("model_field_ut", spec_bench_field_ut)


def calibrate_session(job: SessionJob) -> dict:
    """Calibrate one recording and compute its figures; a plain dict (crosses process boundaries).

    Returns
    -------
    dict
        ``path, sha256, module_id, session_time, kind, calibration`` (file text or None),
        ``figures`` (dict), ``warnings`` (list of str), ``refused`` (the reason, or None),
        ``seconds`` (wall time of the calibration).
    """
    from compass.calibration import CalibrationFileError, from_dict
    from compass.io.table import RecordingError, read_table
    from compass.io.units import RecordingWarning
    from compass.production.figures import module_figures

    from .contract import CannotCalibrate
    from .session import file_text, find_kind, fit_recording

    start = time.perf_counter()
    module_id, session_time = session_identity(job.path)
    out = {"path": job.path, "sha256": job.sha256, "module_id": module_id, "session_time": session_time,
           "kind": None, "calibration": None, "figures": {}, "warnings": [], "refused": None}
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", RecordingWarning)
            table = read_table(job.path)
            found = find_kind(table, job.path)
            out["kind"] = found.name
            _, result = fit_recording(found, table, {})
            document = result.to_json()
            text = file_text(document, job.path)
        out["warnings"] = [str(w.message) for w in caught if issubclass(w.category, RecordingWarning)]
        out["warnings"] += list(result.warnings)
        out["calibration"] = text
        model = from_dict(json.loads(text)).model
        # the diagnosis block of the contract (calibrate.contract: to_json()["diagnosis"])
        bench = None if model.field_ut is not None else bench_field_ut(document, job.bench_field_ut)
        out["figures"] = module_figures(model, document.get("diagnosis"), out["warnings"],
                                        site_dip_deg=job.site_dip_deg, site_field_ut=job.site_field_ut,
                                        bench_field_ut=bench)
    except (RecordingError, CannotCalibrate, CalibrationFileError) as exc:
        out["refused"] = str(exc)
    except Exception as exc:  # noqa: BLE001 - one module's failure is its verdict, never the batch's end
        out["refused"] = f"{job.path}: calibration failed: {type(exc).__name__}: {exc}"
    out["seconds"] = time.perf_counter() - start
    return out


def executor_outcomes(jobs: list[SessionJob], *, workers: int | None = None, scheduler: str | None = None,
                      dask: bool = False):
    """Outcomes of :func:`calibrate_session` over ``jobs``, in the order they finish.

    Parameters
    ----------
    workers : int or None
        0: the serial loop in this process; None or N >= 1: a local process pool of N (default: the
        CPU count), or a Dask ``LocalCluster`` of N single-threaded workers when ``dask``.
    scheduler : str or None
        A Dask scheduler's address (``tcp://host:8786``): the sessions run on its workers.
    dask : bool
        Use Dask distributed (``pip install 'compass-toolkit[dask]'``).
    """
    if scheduler is not None or dask:
        yield from _dask_outcomes(jobs, workers, scheduler)
    elif workers == 0:
        yield from map(calibrate_session, jobs)
    else:
        from concurrent.futures import ProcessPoolExecutor, as_completed

        with ProcessPoolExecutor(max_workers=workers or os.cpu_count(), initializer=_exit_with_parent,
                                 initargs=(os.getpid(),)) as pool:
            futures = [pool.submit(calibrate_session, job) for job in jobs]
            try:
                for future in as_completed(futures):
                    yield future.result()
            finally:
                for future in futures:
                    future.cancel()


_PARENT_POLL_S = 1.0


def _exit_with_parent(parent_pid: int) -> None:
    """A pool worker's initializer: end the worker when the batch that started it is gone.

    A batch killed with ``kill -9`` cannot stop its workers; without this they would sit orphaned
    (their task queue's pipe stays open in their siblings) and calibrate on for nobody.
    """
    import threading

    def watch():
        while os.getppid() == parent_pid:
            time.sleep(_PARENT_POLL_S)
        os._exit(1)

    threading.Thread(target=watch, daemon=True, name="exit-with-parent").start()


def _dask_outcomes(jobs, workers, scheduler):
    try:
        from dask.distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise ImportError("Dask distributed is not installed: pip install 'compass-toolkit[dask]' "
                          "(or run without --scheduler: a local process pool)") from None
    cluster = None
    if scheduler is None:
        cluster = LocalCluster(n_workers=workers or os.cpu_count(), threads_per_worker=1, processes=True,
                               dashboard_address=None)
    client = Client(scheduler or cluster)
    try:
        futures = client.map(calibrate_session, jobs, pure=False)
        for future in as_completed(futures):
            yield future.result()
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


@dataclass
class BatchSummary:
    """What a batch did.

    Attributes
    ----------
    total : int
        Recordings given.
    skipped : int
        Already stored (same recording hash, toolkit version and spec).
    counts : dict
        Status -> number of sessions stored by this run.
    hashes : list of str
        Every recording's hash (the report's sessions).
    duplicates : dict
        ``(module_id, session_time)`` -> the paths of the different recordings (among this run's and
        the store's) that claim it, for each claimed by more than one (:func:`shared_identities`).
    seconds : float
        Wall time of the calibrations.
    """

    total: int
    skipped: int = 0
    counts: dict = field(default_factory=lambda: {"accepted": 0, "rejected": 0, "refused": 0})
    hashes: list = field(default_factory=list)
    duplicates: dict = field(default_factory=dict)
    seconds: float = 0.0


def shared_identities(identities: dict, hashes: dict, store) -> dict:
    """Module id and session time claimed by more than one recording: the recordings' paths.

    Parameters
    ----------
    identities : dict
        Path -> ``(module_id, session_time)`` (:func:`session_identity`) of this run's recordings.
    hashes : dict
        Path -> the recording's SHA-256.
    store : compass.production.store.Store
        Its sessions of the same module and session time count too (of any toolkit version or spec).

    Returns
    -------
    dict
        ``(module_id, session_time)`` -> sorted absolute paths, one a distinct recording hash, for
        each identity with more than one (the same recording given twice is one; a session time of a day alone,
        :func:`compass.production.store.timed`, or a stored recording at the same path is none).
    """
    from compass.production.store import timed

    claims: dict[tuple[str, str], dict[str, str]] = {}
    for p, identity in identities.items():
        if timed(identity[1]):  # at a day alone (compass bench's '# date:') a same-day session is a later one
            claims.setdefault(identity, {}).setdefault(hashes[p], os.path.abspath(p))
    for identity, by_hash in claims.items():  # the same file stored before, edited: superseded, not a claimant
        for row in store.claimants(*identity, hashes=set(by_hash), paths=set(by_hash.values())):
            by_hash.setdefault(row.recording_sha256, row.recording_path)
    return {identity: sorted(by_hash.values()) for identity, by_hash in claims.items() if len(by_hash) > 1}


def duplicate_reason(identity: tuple[str, str], paths) -> str:
    """The verdict's words for a session whose module id and session time another recording claims."""
    module_id, session_time = identity
    return (f"duplicate module id '{module_id}': {len(paths)} different recordings claim its session at "
            f"{session_time}: {', '.join(paths)}; which one is this module's is unknown, so none is accepted: "
            "correct the wrong recording's '# module_id:' and record the module again (a later session decides)")


def _commit(store, outcome: dict, verdict, identity: tuple[str, str], summary: BatchSummary, *, toolkit_version: str,
            spec):
    """Store one session with its verdict, in one transaction holding the store's write lock; the verdict stored.

    The store is looked at again inside the transaction: another batch may have stored a recording claiming this
    session since the run began (:attr:`BatchSummary.duplicates` then gains it)."""
    from compass.production.spec import Verdict

    path = os.path.abspath(outcome["path"])
    with store.transaction():
        stored = store.claimants(*identity, hashes={outcome["sha256"]}, paths={path})
        if stored:
            summary.duplicates[identity] = sorted({*summary.duplicates.get(identity, [path]),
                                                   *(r.recording_path for r in stored)})
        shared = summary.duplicates.get(identity)
        if shared:  # calibrated or not, it cannot be this module's verdict: the recording is ambiguous
            verdict = Verdict("refused" if verdict.status == "refused" else "rejected",
                              (duplicate_reason(identity, shared), *verdict.reasons), verdict.notes)
        store.add(module_id=outcome["module_id"], session_time=outcome["session_time"], recording_path=path,
                  recording_sha256=outcome["sha256"], toolkit_version=toolkit_version, kind=outcome["kind"],
                  status=verdict.status, reasons=verdict.reasons, notes=verdict.notes, figures=outcome["figures"],
                  calibration=outcome["calibration"], spec_text=spec.text, spec_sha256=spec.sha256)
    return verdict


def run_batch(paths, spec, store, *, toolkit_version: str, workers: int | None = None,
              scheduler: str | None = None, dask: bool = False,
              progress: Callable[[str], None] | None = None) -> BatchSummary:
    """Calibrate, judge and store every recording not stored yet.

    Parameters
    ----------
    paths : sequence of path-like
        Recordings (any kind ``compass calibrate`` reads).
    spec : compass.production.spec.AcceptanceSpec
    store : compass.production.store.Store
        Written by this process only, one transaction per session.
    toolkit_version : str
    workers, scheduler, dask
        See :func:`executor_outcomes`.
    progress : callable, optional
        Called with one line per stored session.

    Returns
    -------
    BatchSummary

    Raises
    ------
    SessionTimeError
        A recording's session time cannot be read (before anything is calibrated or stored).
    """
    from compass.production.spec import Verdict

    paths = [str(p) for p in paths]
    summary = BatchSummary(total=len(paths))
    identities = {p: session_identity(p) for p in paths}
    hashes = {p: sha256_of(p) for p in paths}
    summary.hashes = list(hashes.values())
    summary.duplicates = shared_identities(identities, hashes, store)
    known = store.known(toolkit_version, spec.sha256)
    jobs, seen = [], set(known)
    for p in paths:
        if hashes[p] in seen:
            summary.skipped += 1
            continue
        seen.add(hashes[p])  # the same recording twice in one batch is one session
        jobs.append(SessionJob(p, hashes[p], spec.site_dip_deg, spec.site_field_ut, spec.bench_field_ut))
    start = time.perf_counter()
    for done, outcome in enumerate(executor_outcomes(jobs, workers=workers, scheduler=scheduler, dask=dask), 1):
        if outcome["refused"] is not None:
            verdict = Verdict("refused", (outcome["refused"],))
        else:
            verdict = spec.judge(outcome["figures"])
        verdict = _commit(store, outcome, verdict, identities[outcome["path"]], summary,
                          toolkit_version=toolkit_version, spec=spec)
        summary.counts[verdict.status] += 1
        if progress is not None:
            why = f": {verdict.reasons[0]}" if verdict.reasons else ""
            unjudged = f"; {'; '.join(verdict.notes)}" if verdict.notes else ""
            progress(f"[{done}/{len(jobs)}] {outcome['module_id']} {verdict.status}{why}{unjudged}")
    summary.seconds = time.perf_counter() - start
    return summary
