"""The calibration store: one SQLite file, one row a bench session, written by one process.

Schema (version :data:`SCHEMA_VERSION`, in SQLite's ``user_version``; :data:`MIGRATIONS` takes an
older file forward, a newer one is refused in words)::

    sessions(id, module_id, session_time, recording_path, recording_sha256, toolkit_version,
             kind, status, reasons, notes, figures, calibration, spec, spec_sha256, stored_at)

``status`` is ``accepted``, ``rejected`` or ``refused`` (not calibrated); ``reasons``, ``notes``
and ``figures`` are JSON; ``calibration`` is the calibration file's text (NULL when refused).
A session is the same when its recording's hash, the toolkit version and the spec are: a re-run
of a batch skips it (:meth:`Store.known`).  A module's calibration is its latest session, when that
is accepted (:func:`module_outcome`); two different recordings of one module id at one session time
are a tie that :meth:`Store.exportable` refuses to break.  Every row is written in its own transaction, so a
process killed mid-batch leaves every finished session stored and no half of one.

Only the batch's parent process writes (SQLite serialises writers; many writing workers would
wait on its lock); two batches may write one store, each session's duplicate check and row in one
:meth:`Store.transaction` that holds the write lock from its start.  Readers (``compass store``, ``compass export --module``) may run beside it: the
store keeps a write-ahead log (``PATH-wal``, ``PATH-shm`` beside it while open), so they never block
the writer.  Keep it on a local disk (SQLite's WAL needs shared memory, which network file systems
do not give).
"""

from __future__ import annotations

import json
import sqlite3
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import date, datetime, timezone
from pathlib import Path

__all__ = ["MIGRATIONS", "SCHEMA_VERSION", "ModuleOutcome", "SessionRow", "SessionTimeError", "Store", "StoreError",
           "module_outcome", "module_outcomes", "same_session", "session_instant", "session_time_text", "timed"]

MIGRATIONS = (
    # 0 -> 1
    """
    CREATE TABLE sessions (
        id INTEGER PRIMARY KEY,
        module_id TEXT NOT NULL,
        session_time TEXT NOT NULL,
        recording_path TEXT NOT NULL,
        recording_sha256 TEXT NOT NULL,
        toolkit_version TEXT NOT NULL,
        kind TEXT,
        status TEXT NOT NULL CHECK (status IN ('accepted', 'rejected', 'refused')),
        reasons TEXT NOT NULL,
        notes TEXT NOT NULL,
        figures TEXT NOT NULL,
        calibration TEXT,
        spec TEXT NOT NULL,
        spec_sha256 TEXT NOT NULL,
        stored_at TEXT NOT NULL,
        UNIQUE (recording_sha256, toolkit_version, spec_sha256)
    );
    CREATE INDEX sessions_module_time ON sessions (module_id, session_time);
    """,
)
"""SQL taking the schema from version i to i + 1 (append; never edit a released one)."""

SCHEMA_VERSION = len(MIGRATIONS)


class StoreError(ValueError):
    """A store that cannot be used: not SQLite, written by a newer schema, no such module (in words)."""


@dataclass(frozen=True)
class SessionRow:
    """One stored session (JSON columns decoded)."""

    id: int
    module_id: str
    session_time: str
    recording_path: str
    recording_sha256: str
    toolkit_version: str
    kind: str | None
    status: str
    reasons: list
    notes: list
    figures: dict
    calibration: str | None
    spec_sha256: str
    stored_at: str


_COLUMNS = ("id", "module_id", "session_time", "recording_path", "recording_sha256", "toolkit_version", "kind",
            "status", "reasons", "notes", "figures", "calibration", "spec_sha256", "stored_at")


def _row(values) -> SessionRow:
    d = dict(zip(_COLUMNS, values))
    for key in ("reasons", "notes", "figures"):
        d[key] = json.loads(d[key])
    return SessionRow(**d)


@dataclass(frozen=True)
class ModuleOutcome:
    """What one module's sessions come to: the session that decides it, and any recording rivalling it.

    Attributes
    ----------
    module_id : str
    status : {"accepted", "rejected", "refused", "duplicate"}
        The latest session's verdict (a later session supersedes an earlier one, whatever their
        verdicts: the module may have changed since); ``duplicate``: another recording (a different
        hash) claims that session's time, so which one is the module's is unknown.
    row : SessionRow
        The latest session.
    rivals : tuple of SessionRow
        The other recordings at ``row``'s session time (one row a recording hash).
    """

    module_id: str
    status: str
    row: SessionRow
    rivals: tuple[SessionRow, ...]


class SessionTimeError(ValueError):
    """A session time that is neither an ISO 8601 time nor a day (the message quotes it)."""


def session_time_text(text: str) -> str:
    """A recording's session time as stored: the UTC instant (``2026-03-02T07:30:00+00:00``), or the day alone.

    ``datetime.fromisoformat``'s forms: an offset (``+02:00``, ``Z``) is applied; a time without one is taken as
    UTC (the bench PC's zone is not in the file; the file's modification time is UTC too); a day alone
    (``2026-03-02``: ``compass bench``'s ``# date:``) stays a day (:func:`timed`).

    Raises
    ------
    SessionTimeError
        Neither form (``2026-3-9``: not zero-padded; ``03/02/2026``).
    """
    text = text.strip()
    if len(text) == 10:  # YYYY-MM-DD (fromisoformat would take it for midnight)
        try:
            return date.fromisoformat(text).isoformat()
        except ValueError:
            pass
    try:
        instant = datetime.fromisoformat(text)
    except ValueError:
        raise SessionTimeError(f"{text!r} is not an ISO 8601 time (2026-03-02T09:30:00+02:00, 2026-03-02T07:30:00Z) "
                               "nor a day (2026-03-02)") from None
    if instant.tzinfo is None:
        instant = instant.replace(tzinfo=timezone.utc)
    return instant.astimezone(timezone.utc).isoformat()


def timed(session_time: str) -> bool:
    """Whether a session time tells the time of day (``2026-03-02T07:24:00``), not the day alone (``# date:``, which
    ``compass bench`` writes: a module recorded again the same day is a later session, not a rival)."""
    return "T" in session_time or ":" in session_time


def session_instant(session_time: str) -> datetime:
    """The UTC instant a stored session time orders by (a day alone: its start, 00:00 UTC).

    Stores written before session times were normalised hold them as the recording wrote them; they are
    parsed here (:func:`session_time_text`).

    Raises
    ------
    SessionTimeError
    """
    text = session_time_text(session_time)
    if not timed(text):
        return datetime.combine(date.fromisoformat(text), datetime.min.time(), timezone.utc)
    return datetime.fromisoformat(text)


_UNREADABLE = datetime.min.replace(tzinfo=timezone.utc)
"""Where a stored session time that cannot be read orders (:func:`stored_instant`)."""


def stored_instant(session_time: str) -> datetime:
    """:func:`session_instant` of a stored session time; one an older store kept as written that is no ISO time
    (``2026-3-9``) is :data:`_UNREADABLE`: it orders first, so it is never a module's latest session over one
    that can be read, and it ties with none."""
    try:
        return session_instant(session_time)
    except SessionTimeError:
        return _UNREADABLE


def same_session(a: str, b: str) -> bool:
    """Whether two session times of day are one instant (``...Z`` and ``...+00:00`` are); days alone never are, nor
    a stored time that cannot be read."""
    return timed(a) and timed(b) and stored_instant(a) == stored_instant(b) != _UNREADABLE


def _at(rows, session_time: str) -> list:
    """The rows at a session time given by a user (any ISO form; a day matches a day-stamped session)."""
    wanted = session_time_text(session_time)
    if timed(wanted):
        return [r for r in rows if same_session(r.session_time, wanted)]
    day = session_instant(wanted)
    return [r for r in rows if not timed(r.session_time) and stored_instant(r.session_time) == day]


def _order(r: "SessionRow"):
    """Session-time order: the instant, then the recording's path (days alone keep their files' order), then the row."""
    return stored_instant(r.session_time), r.recording_path, r.id


def module_outcome(rows) -> ModuleOutcome:
    """The outcome of one module from its sessions in session-time order (:meth:`Store.sessions`).

    The latest session decides (a later session of the module supersedes an earlier one, a later
    rejection an earlier acceptance); the same recording stored twice (another toolkit version or
    spec) is one recording, its latest judgment deciding.  Sessions at
    one session time of day (:func:`timed`) are not ordered by anything but their files' names, so two
    different recordings there are a tie, never a choice, unless they are the same file (edited, or
    recorded again over it: one module's, not rivals); at a day alone the later file name decides.
    """
    rows = list(rows)
    row = rows[-1]
    rivals = {r.recording_sha256: r for r in rows
              if same_session(r.session_time, row.session_time)
              and r.recording_sha256 != row.recording_sha256 and r.recording_path != row.recording_path}
    status = "duplicate" if rivals else row.status
    return ModuleOutcome(row.module_id, status, row, tuple(rivals.values()))


def module_outcomes(rows, rivals=()) -> list[ModuleOutcome]:
    """:func:`module_outcome` of every module among ``rows`` (session-time order), in order of first session.

    ``rivals`` (:meth:`Store.rivals`: other recordings in the store claiming a session of ``rows``) take part in their
    modules' outcomes: a module one of them rivals is a duplicate id, as it would be with both in ``rows``.
    """
    by_module: dict[str, list[SessionRow]] = {}
    for r in sorted([*rows, *rivals], key=_order):
        by_module.setdefault(r.module_id, []).append(r)
    return [module_outcome(group) for group in by_module.values()]


class Store:
    """The store at ``path`` (created with the current schema when absent).

    Raises
    ------
    StoreError
        The file is not an SQLite database, or its schema is newer than this toolkit knows.
    """

    def __init__(self, path, *, create: bool = True):
        self.path = Path(path)
        if not create and not self.path.exists():
            raise StoreError(f"{self.path}: no such store")
        try:
            self._db = sqlite3.connect(self.path, timeout=60.0, isolation_level=None)
            version = self._db.execute("PRAGMA user_version").fetchone()[0]
        except sqlite3.DatabaseError as exc:
            raise StoreError(f"{self.path}: not a calibration store (SQLite says: {exc})") from None
        if version > SCHEMA_VERSION:
            self._db.close()
            raise StoreError(f"{self.path}: written by a newer compass (store schema {version}; this compass "
                             f"knows up to {SCHEMA_VERSION}): upgrade compass to read it; it was left unchanged")
        # write-ahead log, synced at checkpoints: a commit is one append, not two syncs (the rollback
        # journal stored 22 sessions/s on this machine's shared disk, the WAL hundreds:
        # tools/bench_batch.py).  A killed process loses no committed session (the log is in the
        # file system); a power cut may roll back the last few, never leave half of one.
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute("PRAGMA synchronous=NORMAL")
        if version < SCHEMA_VERSION:
            self._migrate(version)

    def _migrate(self, version: int) -> None:
        """Apply the migrations after ``version``, all in one transaction with the new version."""
        db = self._db
        with self.transaction():
            current = db.execute("PRAGMA user_version").fetchone()[0]  # another process may have migrated
            for sql in MIGRATIONS[current:]:
                for statement in filter(str.strip, sql.split(";")):
                    db.execute(statement)
            db.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")

    @contextmanager
    def transaction(self):
        """One write transaction holding the store's write lock from its start (SQLite's ``BEGIN IMMEDIATE``): what
        is read inside it is what its writes commit against, whatever another process writes meanwhile (that one
        waits); rolled back whole on any exception."""
        self._db.execute("BEGIN IMMEDIATE")
        try:
            yield self
        except BaseException:
            self._db.execute("ROLLBACK")
            raise
        self._db.execute("COMMIT")

    def close(self) -> None:
        self._db.close()

    def __enter__(self) -> "Store":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ writing

    def add(self, *, module_id: str, session_time: str, recording_path: str, recording_sha256: str,
            toolkit_version: str, kind: str | None, status: str, reasons, notes, figures: dict,
            calibration: str | None, spec_text: str, spec_sha256: str) -> bool:
        """Store one session (its own transaction, or part of :meth:`transaction`); False when already stored."""
        stored_at = datetime.now(timezone.utc).isoformat(timespec="seconds")
        cur = self._db.execute(
            "INSERT OR IGNORE INTO sessions (module_id, session_time, recording_path, recording_sha256, "
            "toolkit_version, kind, status, reasons, notes, figures, calibration, spec, spec_sha256, stored_at) "
            "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
            (module_id, session_time, recording_path, recording_sha256, toolkit_version, kind, status,
             json.dumps(list(reasons)), json.dumps(list(notes)), json.dumps(figures), calibration, spec_text,
             spec_sha256, stored_at))
        return cur.rowcount == 1

    # ------------------------------------------------------------------ reading

    def known(self, toolkit_version: str, spec_sha256: str) -> set[str]:
        """Hashes of the recordings already stored for this toolkit version and spec."""
        rows = self._db.execute("SELECT recording_sha256 FROM sessions WHERE toolkit_version = ? AND spec_sha256 = ?",
                                (toolkit_version, spec_sha256))
        return {r[0] for r in rows}

    def sessions(self, *, module_id: str | None = None, hashes=None) -> list[SessionRow]:
        """Stored sessions in session-time order, then by recording path (sessions stamped with a day
        only keep their files' order), of one module or of some recordings' hashes."""
        sql, args = f"SELECT {', '.join(_COLUMNS)} FROM sessions", []
        if module_id is not None:
            sql, args = sql + " WHERE module_id = ?", [module_id]
        rows = [_row(r) for r in self._db.execute(sql, args)]
        if hashes is not None:
            hashes = set(hashes)
            rows = [r for r in rows if r.recording_sha256 in hashes]
        return sorted(rows, key=_order)

    def rivals(self, rows) -> list[SessionRow]:
        """Stored sessions of other recordings claiming a session of ``rows``: the same module id and session time of
        day (:func:`timed`), another hash and another path than every row of that session (:func:`module_outcome`'s
        rivals), in session-time order.  A batch's report counts a module they rival as a duplicate id."""
        claimed: dict[tuple[str, datetime], list[SessionRow]] = {}
        for r in rows:
            if timed(r.session_time):
                claimed.setdefault((r.module_id, stored_instant(r.session_time)), []).append(r)
        found = {}
        for (module_id, _), own in claimed.items():
            found.update((r.id, r) for r in self.claimants(module_id, own[0].session_time,
                                                           hashes={o.recording_sha256 for o in own},
                                                           paths={o.recording_path for o in own}))
        return sorted(found.values(), key=_order)

    def claimants(self, module_id: str, session_time: str, *, hashes, paths) -> list[SessionRow]:
        """Stored sessions of other recordings claiming a module id and session time of day (:func:`same_session`):
        a hash not in ``hashes`` and a path not in ``paths`` (the same file edited is the module's own)."""
        if not timed(session_time):
            return []
        return [r for r in self.sessions(module_id=module_id) if same_session(r.session_time, session_time)
                and r.recording_sha256 not in hashes and r.recording_path not in paths]

    def exportable(self, module_id: str, session_time: str | None = None) -> SessionRow:
        """The module's calibration to hand out: its latest session (:func:`module_outcome`), or the one at
        ``session_time``, when that session is accepted and no other recording claims its time.

        Raises
        ------
        StoreError
            No session of that module (at that time); the session not accepted (the message names it, its
            reasons and the latest accepted session before it); or another recording claims its time (the
            message names every recording).
        """
        rows = self.sessions(module_id=module_id)
        if not rows:
            raise StoreError(f"{self.path}: no session of module '{module_id}'")
        if session_time is not None:
            chosen = _at(rows, session_time)
            if not chosen:
                raise StoreError(f"{self.path}: module '{module_id}' has no session at {session_time}; its sessions: "
                                 + ", ".join(dict.fromkeys(r.session_time for r in rows)))
            rows = rows[:rows.index(chosen[-1]) + 1]
        outcome = module_outcome(rows)
        row = outcome.row
        if outcome.rivals:
            claims = ", ".join(f"{r.recording_path} (sha256 {r.recording_sha256[:12]}, {r.status})"
                               for r in sorted((row, *outcome.rivals), key=lambda r: r.recording_path))
            raise StoreError(f"{self.path}: module '{module_id}': {1 + len(outcome.rivals)} different recordings "
                             f"claim its session {row.session_time}: {claims}; none is later, so "
                             "which calibration is this module's is unknown: correct the wrong recording's "
                             "'# module_id:' and record the module again (a later session decides), or export "
                             "the calibration file of the right recording")
        if row.status != "accepted":
            why = "; ".join(row.reasons) or row.status
            earlier = [r for r in rows if r.status == "accepted"]
            hint = (f"; an earlier session, {earlier[-1].session_time}, was accepted: export --module {module_id} "
                    f"--session {earlier[-1].session_time} hands it out, if the module has not changed since"
                    if earlier else "; no session of it was accepted")
            raise StoreError(f"{self.path}: module '{module_id}': its {'' if session_time else 'latest '}session, "
                             f"{row.session_time} ({row.recording_path}), was {row.status}: {why}{hint}")
        return row

    def count(self) -> int:
        return self._db.execute("SELECT COUNT(*) FROM sessions").fetchone()[0]
