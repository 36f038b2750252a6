"""compass batch / store / export --module on a small simulated line (14 short sessions, 7 defects)."""

import json
import os
import re
import signal
import sqlite3
import time

import pytest

from calibrate.batch import run_batch
from compass.calibration import from_dict
from compass.cli import main
from compass.production.spec import DEFAULT_SPEC, load_spec
from compass.production.store import Store, StoreError
from compass.sim.fleet import FleetOptions, simulate_fleet
from tests._proc import Proc, compass_command

N = 14  # at least two of each of the 7 defects' slots: every defect once, 7 clean modules


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    folder = tmp_path_factory.mktemp("fleet")
    truth = simulate_fleet(folder / "line", FleetOptions(n=N, seed=5, step_deg=10.0))
    return folder, truth


def _batch(*args, timeout_s=300.0, **kw):
    with Proc(compass_command("batch", *map(str, args)), kill_after_s=timeout_s, **kw) as proc:
        return proc.wait(timeout_s), "".join(proc.out), "".join(proc.err)


def test_simulated_line_truth(fleet):
    _, truth = fleet
    defects = [m["defect"] for m in truth["modules"] if m["defect"]]
    assert sorted(defects) == sorted(("dead_channel", "noisy_channel", "misaligned_channel", "magnetised",
                                      "weak_channel", "truncated", "corrupt"))
    assert all(m["should_fail"] == (m["defect"] is not None) for m in truth["modules"])
    dips = [m["bench_dip_deg"] for m in truth["modules"]]
    start = truth["drift"]["start_session"]
    assert dips[: start + 1] == [dips[0]] * (start + 1) and dips[-1] > dips[0]


def test_batch_judges_stores_and_reports_every_module(fleet):
    folder, truth = fleet
    out = folder / "results"
    status, stdout, stderr = _batch(folder / "line", "--out", out, "--workers", "2")
    assert status == 0, stderr
    assert f"{N} recordings: {N} calibrated now" in stdout
    with Store(out / "calibrations.sqlite", create=False) as store:
        rows = {r.module_id: r for r in store.sessions()}
    assert len(rows) == N
    for m in truth["modules"]:
        row = rows[m["module_id"]]
        assert row.session_time == m["session_time"]
        if m["should_fail"]:
            assert row.status in ("rejected", "refused") and row.reasons, m["defect"]
        if m["defect"] in ("truncated", "corrupt"):
            assert row.status == "refused" and row.calibration is None
            assert row.reasons[0].startswith(str(folder / "line" / m["file"]))
        if row.calibration is not None:
            assert from_dict(json.loads(row.calibration)).model is not None
    clean = [rows[m["module_id"]].status for m in truth["modules"] if not m["should_fail"]]
    assert clean.count("accepted") >= len(clean) - 1
    dead = rows[_module(truth, "dead_channel")]
    assert dead.status == "refused" and "does not respond to the field" in dead.reasons[0]  # calibrate.health
    misaligned = rows[_module(truth, "misaligned_channel")].reasons
    assert any(r.startswith("axis_misalignment_deg") for r in misaligned)
    assert "warning of class 'channel'" in misaligned  # calibrate.health's words, classified
    noisy = rows[_module(truth, "noisy_channel")].reasons
    assert any(r.startswith("snr_ratio_min") for r in noisy) and "warning of class 'channel'" in noisy
    report = (out / "report.html").read_text()
    assert "Yield" in report and "Failed modules" in report and "data:image/png;base64," in report
    assert "no chart: a control chart needs more than its 50 baseline sessions" in report
    csv_lines = (out / "figures.csv").read_text().splitlines()
    assert len(csv_lines) == N + 1 and csv_lines[0].startswith("module_id,session_time,status,kind,")



def test_a_rerun_skips_what_is_stored_and_the_report_needs_force(fleet, capsys):
    folder, _ = fleet
    out = folder / "results"
    if not (out / "report.html").exists():
        pytest.skip("needs test_batch_judges_stores_and_reports_every_module's results")
    assert main(["batch", str(folder / "line"), "--out", str(out), "--workers", "0"]) == 2
    assert "report.html exists (an earlier batch's report: a re-run resumes the batch" in capsys.readouterr().err
    with Store(out / "calibrations.sqlite", create=False) as store:
        summary = run_batch(sorted((folder / "line").glob("*.csv")), load_spec(), store,
                            toolkit_version=store.sessions()[0].toolkit_version, workers=0)
        assert summary.skipped == N and sum(summary.counts.values()) == 0 and store.count() == N


def _module(truth, defect):
    return next(m["module_id"] for m in truth["modules"] if m["defect"] == defect)


def test_store_and_export_read_the_batch(fleet, capsys):
    folder, truth = fleet
    store = folder / "results" / "calibrations.sqlite"
    if not store.exists():
        pytest.skip("needs test_batch_judges_stores_and_reports_every_module's store")
    assert main(["store", "list", "--store", str(store)]) == 0
    assert f"{N} session(s)" in capsys.readouterr().out
    accepted = next(m["module_id"] for m in truth["modules"] if not m["should_fail"])
    assert main(["export", "--module", accepted, "--store", str(store)]) == 0
    captured = capsys.readouterr()
    assert from_dict(json.loads(captured.out)).model.channels == ("v1", "v2", "v3")
    assert f"module {accepted}" in captured.err and "(accepted;" in captured.err
    weak = _module(truth, "weak_channel")
    assert main(["export", "--module", weak, "--store", str(store), "--format", "fusion"]) == 2
    err = capsys.readouterr().err
    assert f"module '{weak}': its latest session" in err and "rejected: gain_spread" in err
    assert main(["store", "show", _module(truth, "corrupt"), "--store", str(store)]) == 0
    shown = capsys.readouterr().out
    # its kind is found from the header (a channel may hold text until a reader uses it), the cell then refused
    assert ": refused (fourflip)" in shown and "column 'v1': expected a number, found 'ERR'" in shown
    assert main(["export", "--module", accepted]) == 2
    assert "--module needs --store PATH" in capsys.readouterr().err


def _clean(truth, k):
    return [m for m in truth["modules"] if not m["should_fail"]][k]


def _relabel(source, like, out):
    """``source``'s samples under ``like``'s '# module_id:' and '# date:' (a header copied by mistake)."""
    header = {line.split(":")[0]: line for line in like.read_text().splitlines() if line.startswith("#")}
    out.write_text("\n".join(header.get(line.split(":")[0], line) if line.startswith("#") else line
                             for line in source.read_text().splitlines()) + "\n")
    return out


def test_two_recordings_claiming_one_module_and_session_are_both_rejected_and_export_refuses(fleet, tmp_path, capsys):
    folder, truth = fleet
    own, other = _clean(truth, 0), _clean(truth, 1)
    line = tmp_path / "line"
    line.mkdir()
    real = line / own["file"]
    real.write_bytes((folder / "line" / own["file"]).read_bytes())
    (line / "copy_of_real.csv").write_bytes(real.read_bytes())  # the same recording twice is one session
    fake = _relabel(folder / "line" / other["file"], real, line / f"{own['module_id']}_rerun.csv")
    (line / other["file"]).write_bytes((folder / "line" / other["file"]).read_bytes())
    out = tmp_path / "r"
    assert main(["batch", str(line), "--out", str(out), "--workers", "0"]) == 0
    captured = capsys.readouterr()
    mid = own["module_id"]
    assert f"duplicate module id {mid}: 2 different recordings claim its session at {own['session_time']}: " \
           f"{real}, {fake}: none accepted" in captured.out
    assert "yield 1/2 modules (50.0 %; 3 sessions)" in captured.out  # the other module accepted, mid not
    assert captured.err.count(f"{mid} rejected: duplicate module id '{mid}'") == 2
    store = out / "calibrations.sqlite"
    with Store(store, create=False) as s:
        rows = s.sessions(module_id=mid)
        assert s.count() == 3 and [r.status for r in rows] == ["rejected", "rejected"]
        assert all(f"{real}, {fake}" in r.reasons[0] and r.calibration is not None for r in rows)
    assert main(["export", "--module", mid, "--store", str(store)]) == 2
    err = capsys.readouterr().err
    assert f"module '{mid}': 2 different recordings claim its session" in err and f"{real} (sha256" in err
    report = (out / "report.html").read_text()
    assert "Duplicate module ids" in report and f"{mid} at {own['session_time']}: {real}, {fake}" in report
    assert main(["batch", str(line), "--out", str(out), "--workers", "0", "--force"]) == 0  # a re-run keeps it
    assert "0 calibrated now" in capsys.readouterr().out


def test_a_tie_with_a_stored_session_is_rejected_and_a_later_session_wins(fleet, tmp_path, capsys):
    folder, truth = fleet
    own, other = _clean(truth, 0), _clean(truth, 1)
    real = folder / "line" / own["file"]
    fake = _relabel(folder / "line" / other["file"], real, tmp_path / "rerun.csv")
    spec = load_spec()
    with Store(tmp_path / "s.sqlite") as store:
        run_batch([real], spec, store, toolkit_version="t", workers=0)
        summary = run_batch([fake], spec, store, toolkit_version="t", workers=0)  # a later batch
        assert summary.duplicates == {(own["module_id"], own["session_time"]): sorted([str(real), str(fake)])}
        first, second = store.sessions(module_id=own["module_id"])
        assert first.status == "accepted" and second.status == "rejected"
        words = re.escape(f"2 different recordings claim its session {own['session_time']}: {real} ")
        with pytest.raises(StoreError, match=words + f"\\(sha256 .*, accepted\\), {re.escape(str(fake))} "):
            store.exportable(own["module_id"])
        later = tmp_path / "later.csv"
        later.write_text(real.read_text().replace(f"# date: {own['session_time']}", "# date: 2099-01-01T00:00:00"))
        run_batch([later], spec, store, toolkit_version="t", workers=0)
        assert store.exportable(own["module_id"]).recording_path == str(later)


def test_a_later_batch_counts_a_store_only_rival_as_a_duplicate_and_a_recalibration_as_its_session(fleet, tmp_path,
                                                                                                    capsys):
    """The second batch's yield over its two modules: one claims a session another recording in the store (not in this
    batch) holds, a duplicate id listed with both files, not a failed limit; the other was calibrated again later, a
    normal thing on a line, decided by its new session."""
    folder, truth = fleet
    own, other = _clean(truth, 0), _clean(truth, 1)
    first, second = tmp_path / "a", tmp_path / "b"
    first.mkdir()
    second.mkdir()
    real = first / own["file"]
    real.write_bytes((folder / "line" / own["file"]).read_bytes())
    (first / other["file"]).write_bytes((folder / "line" / other["file"]).read_bytes())
    fake = _relabel(folder / "line" / other["file"], real, second / f"{own['module_id']}_rerun.csv")
    again = second / other["file"]
    again.write_text((first / other["file"]).read_text().replace(f"# date: {other['session_time']}",
                                                                 "# date: 2099-01-01T00:00:00"))
    store = tmp_path / "s.sqlite"
    assert main(["batch", str(first), "--out", str(tmp_path / "r1"), "--workers", "0", "--store", str(store)]) == 0
    capsys.readouterr()
    assert main(["batch", str(second), "--out", str(tmp_path / "r2"), "--workers", "0", "--store", str(store)]) == 0
    assert "yield 1/2 modules (50.0 %; 2 sessions)" in capsys.readouterr().out
    report = (tmp_path / "r2" / "report.html").read_text()
    accepted, rejected, refused, duplicate = 1, 0, 0, 1
    assert (f"<tr><td class='num ok'>{accepted}</td><td class='num bad'>{rejected}</td><td class='num bad'>{refused}"
            f"</td><td class='num bad'>{duplicate}</td><td class='num'><b>50.0 %</b></td></tr>") in report
    assert f"{own['module_id']} at {own['session_time']}: {real}, {fake}" in report


def test_an_all_refused_batch_report_says_nothing_to_plot_not_empty_plots(tmp_path, capsys):
    line = tmp_path / "line"
    line.mkdir()
    for k in range(2):  # no channel columns: refused, each naming its file
        (line / f"M{k}.csv").write_text(f"# module_id: M{k}\nflip_deg,platform_deg\n0,0\n0,1\n")
    assert main(["batch", str(line), "--out", str(tmp_path / "r"), "--workers", "0"]) == 0
    assert "yield 0/2 modules" in capsys.readouterr().out
    report = (tmp_path / "r" / "report.html").read_text()
    assert "nothing to plot (every session was refused" in report and "<figure>" not in report
    assert "Failed modules (2)" in report


def test_a_malformed_spec_is_exit_2_naming_the_key(fleet, tmp_path, capsys):
    folder, _ = fleet
    spec = tmp_path / "acceptance.toml"
    spec.write_text("[limits]\ngain_spread = { max = 'wide' }\n")
    assert main(["batch", str(folder / "line"), "--spec", str(spec), "--out", str(tmp_path / "r")]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f"compass batch: {spec}: 'limits.gain_spread.max': expected a number, got 'wide'"]
    assert not (tmp_path / "r").exists()


def test_an_empty_spec_is_exit_2_naming_the_file_not_every_module_accepted(fleet, tmp_path, capsys):
    folder, _ = fleet
    spec = tmp_path / "empty.toml"
    spec.write_text("")
    assert main(["batch", str(folder / "line"), "--spec", str(spec), "--out", str(tmp_path / "r")]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f"compass batch: {spec}: no [limits]: the spec judges no figure, so every module would be accepted (an empty "
        "or truncated file?); give limits like [limits] gain_spread = { max = 0.3 } (the default spec: "
        f"{DEFAULT_SPEC})"]
    assert not (tmp_path / "r").exists()


def test_a_store_of_a_newer_schema_is_refused_in_words(fleet, tmp_path, capsys):
    folder, _ = fleet
    store = tmp_path / "future.sqlite"
    with sqlite3.connect(store) as db:
        db.execute("PRAGMA user_version = 99")
    assert main(["batch", str(folder / "line" / "M0001.csv"), "--store", str(store), "--out", str(tmp_path)]) == 2
    assert "written by a newer compass (store schema 99; this compass knows up to 1)" in capsys.readouterr().err
    assert main(["store", "list", "--store", str(store)]) == 2
    assert "upgrade compass to read it" in capsys.readouterr().err


def _group_alive(pgid) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    return True


def test_kill_9_mid_batch_loses_nothing_and_stores_nothing_twice(fleet, tmp_path):
    folder, truth = fleet
    out = tmp_path / "killed"
    store_path = out / "calibrations.sqlite"
    with Proc(compass_command("batch", str(folder / "line"), "--out", str(out), "--workers", "2"),
              kill_after_s=300, group=True) as proc:
        deadline = time.monotonic() + 240
        stored = 0
        while time.monotonic() < deadline and proc.popen.poll() is None:
            if store_path.exists():
                with sqlite3.connect(store_path, timeout=30) as db:
                    try:
                        stored = db.execute("SELECT COUNT(*) FROM sessions").fetchone()[0]
                    except sqlite3.OperationalError:  # the table is being created
                        stored = 0
                if stored >= 3:
                    break
            time.sleep(0.05)
        assert proc.popen.poll() is None and stored >= 3, proc.transcript()
        os.kill(proc.popen.pid, signal.SIGKILL)  # kill -9 of the batch: its pool workers see it gone and end
        proc.popen.wait(30)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and _group_alive(proc.popen.pid):
            time.sleep(0.1)
        assert not _group_alive(proc.popen.pid), "pool workers outlived their killed batch"
    with Store(store_path, create=False) as store:
        survivors = store.sessions()
    assert 3 <= len(survivors) < N
    for row in survivors:  # every stored session is whole
        assert row.status in ("accepted", "rejected", "refused") and row.figures is not None
        assert (row.calibration is None) == (row.status == "refused")
    status, stdout, stderr = _batch(folder / "line", "--out", out, "--workers", "2")
    assert status == 0, stderr
    assert f"{N - len(survivors)} calibrated now" in stdout and f"{len(survivors)} already stored" in stdout
    with Store(store_path, create=False) as store:
        rows = store.sessions()
    assert sorted(r.module_id for r in rows) == sorted(m["module_id"] for m in truth["modules"])
    before = {r.recording_sha256: r for r in survivors}
    for r in rows:  # the survivors were kept as they were, not calibrated again
        if r.recording_sha256 in before:
            assert r.id == before[r.recording_sha256].id and r.stored_at == before[r.recording_sha256].stored_at


def test_batch_takes_any_kind(fleet, tmp_path):
    from compass.sim.tumble import simulate_tumble, write_tumble

    folder, _ = fleet
    tumble = tmp_path / "tumble.csv"
    write_tumble(simulate_tumble(seed=3, n=600), tumble)
    with Store(tmp_path / "s.sqlite") as store:
        run_batch([tumble, folder / "line" / "M0001.csv"], load_spec(), store, toolkit_version="t", workers=0)
        rows = {r.kind: r for r in store.sessions()}
    assert set(rows) == {"tumble", "fourflip"}
    assert rows["tumble"].module_id == "tumble" and rows["fourflip"].module_id == "M0001"
    assert rows["tumble"].status != "refused"
    assert "direction_sigma_deg: not judged: not given by this calibration" in rows["tumble"].notes


def test_dask_local_cluster_gives_the_pool_s_verdicts(fleet, tmp_path):
    pytest.importorskip("dask.distributed", reason="Dask is optional: pip install 'compass-toolkit[dask]'")
    from calibrate.batch import run_batch
    from compass.production.spec import load_spec

    folder, truth = fleet
    paths = [folder / "line" / m["file"] for m in truth["modules"][:2]]
    spec = load_spec()
    with Store(tmp_path / "d.sqlite") as dask_store, Store(tmp_path / "s.sqlite") as serial_store:
        run_batch(paths, spec, dask_store, toolkit_version="t", workers=1, dask=True)
        run_batch(paths, spec, serial_store, toolkit_version="t", workers=0)
        got = {r.module_id: (r.status, r.figures) for r in dask_store.sessions()}
        expected = {r.module_id: (r.status, r.figures) for r in serial_store.sessions()}
    assert got == expected and len(got) == 2


def test_simulate_fleet_command_writes_sessions_and_truth_and_never_overwrites(tmp_path, capsys):
    out = tmp_path / "line"
    assert main(["simulate", "fleet", "--n", "4", "--out", str(out), "--step-deg", "30", "--drift-start", "2"]) == 0
    truth = json.loads((out / "fleet_truth.json").read_text())
    assert [m["file"] for m in truth["modules"]] == ["M0001.csv", "M0002.csv", "M0003.csv", "M0004.csv"]
    assert truth["drift"]["start_session"] == 2
    assert "# module_id: M0003" in (out / "M0003.csv").read_text()
    capsys.readouterr()
    assert main(["simulate", "fleet", "--n", "4", "--out", str(out)]) == 2
    assert "exists; use --force" in capsys.readouterr().err


def test_a_clipped_channel_s_session_is_refused_naming_it(fleet, tmp_path):
    from calibrate.batch import SessionJob, calibrate_session, sha256_of

    folder, truth = fleet
    lines = (folder / "line" / _clean(truth, 2)["file"]).read_text().splitlines()
    header = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    v2 = lines[header].split(",").index("v2")
    rail = 0.9 * max(float(line.split(",")[v2]) for line in lines[header + 1:])
    clipped = tmp_path / "clipped.csv"
    clipped.write_text("\n".join(lines[: header + 1] + [
        ",".join(f"{min(float(c), rail):.3f}" if k == v2 else c for k, c in enumerate(line.split(",")))
        for line in lines[header + 1:]]) + "\n")
    out = calibrate_session(SessionJob(str(clipped), sha256_of(clipped), 65.0, 50.0))
    assert out["refused"].startswith(f"{clipped}, row ") and "column 'v2': reads its extreme" in out["refused"]
    assert "clipped (saturated)" in out["refused"] and "'v1'" not in out["refused"] and "'v3'" not in out["refused"]


def _without_field_ut(source, out, extra=()):
    """``source`` as ``compass bench`` writes a recording (no '# field_ut:'), its module id the file name, ``extra`` added."""
    lines = [line for line in source.read_text().splitlines() if not line.startswith(("# field_ut:", "# module_id:"))]
    out.write_text("\n".join([*extra, *lines]) + "\n")
    return out


def test_a_magnetised_module_without_field_ut_is_judged_by_the_bench_field_or_said_unjudged(fleet, tmp_path):
    folder, truth = fleet
    magnetised = folder / "line" / truth["modules"][[m["defect"] for m in truth["modules"]].index("magnetised")]["file"]
    bare = _without_field_ut(magnetised, tmp_path / "bare.csv")
    sited = _without_field_ut(magnetised, tmp_path / "sited.csv",
                              ["# site_lat_deg: 48.1", "# site_lon_deg: 11.6", "# site_alt_m: 520"])
    lines = []
    with Store(tmp_path / "s.sqlite") as store:
        run_batch([bare, sited], load_spec(), store, toolkit_version="t", workers=0, progress=lines.append)
        rows = {r.recording_path: r for r in store.sessions()}
    assert rows[str(sited)].status == "rejected" and "offset_ut" in rows[str(sited)].reasons[0]  # WMM: 48.6 uT
    assert rows[str(bare)].status == "accepted"
    assert any("accepted; offset_ut: not judged: the bench's |B| in uT is unknown" in x for x in lines)
    spec = tmp_path / "spec.toml"
    spec.write_text(load_spec().text.replace("[site]", "[site]\nbench_field_ut = 48.0", 1))
    with Store(tmp_path / "t.sqlite") as store:
        run_batch([bare], load_spec(spec), store, toolkit_version="t", workers=0)
        assert store.sessions()[0].reasons[0].startswith("offset_ut ")


def test_bench_writes_the_sites_field_as_field_ut():
    import argparse

    from compass.commands.bench import _metadata
    from compass.site import Site

    site = Site.parse("48.1,11.6,520", "2026-03-02")
    args = argparse.Namespace(module_id="M1", operator="op", date=None)
    meta = _metadata(args, argparse.Namespace(spec="grbl"), site)
    assert float(meta["field_ut"]) == pytest.approx(site.field().field_ut, abs=1e-3)
    assert "field_ut" not in _metadata(args, argparse.Namespace(spec="grbl"), None)


def test_a_batch_with_an_unreadable_session_time_stops_before_storing_naming_the_file(fleet, tmp_path):
    folder, truth = fleet
    good = folder / "line" / truth["modules"][0]["file"]
    bad = tmp_path / "bad.csv"
    bad.write_text("# date: 2026-3-9\n" + "\n".join(line for line in good.read_text().splitlines()
                                                       if not line.startswith("# date:")) + "\n")
    code, out, err = _batch(good, bad, "--out", tmp_path / "r", "--workers", "0", timeout_s=120.0)
    assert code == 2 and "Traceback" not in err
    assert f"{bad}: '# date:' '2026-3-9' is not an ISO 8601 time" in err
    with Store(tmp_path / "r" / "calibrations.sqlite", create=False) as store:
        assert store.count() == 0


def test_a_module_rejected_at_its_later_session_counts_failed_and_export_refuses_unless_asked_for_the_earlier(
        fleet, tmp_path, capsys):
    folder, truth = fleet
    own = _clean(truth, 0)
    magnetised = next(m for m in truth["modules"] if m["defect"] == "magnetised")
    line = tmp_path / "line"
    line.mkdir()
    monday = line / "monday.csv"
    monday.write_bytes((folder / "line" / own["file"]).read_bytes())
    tuesday = _relabel(folder / "line" / magnetised["file"], monday, line / "tuesday.csv")  # the module, magnetised since
    tuesday.write_text(tuesday.read_text().replace(f"# date: {own['session_time']}", "# date: 2026-03-03T07:00:00Z"))
    store = tmp_path / "r" / "calibrations.sqlite"
    assert main(["batch", str(line), "--out", str(tmp_path / "r"), "--workers", "0"]) == 0
    assert "yield 0/1 modules (0.0 %; 2 sessions)" in capsys.readouterr().out
    assert main(["export", "--module", own["module_id"], "--store", str(store)]) == 2
    err = capsys.readouterr().err
    assert (f"its latest session, 2026-03-03T07:00:00+00:00 ({tuesday}), was rejected: offset_ut" in err
            and f"--session {own['session_time']} hands it out" in err)
    out = tmp_path / "monday.json"
    assert main(["export", "--module", own["module_id"], "--store", str(store), "--session", own["session_time"],
                 "--out", str(out)]) == 0
    with Store(store, create=False) as kept:
        assert out.read_text() == next(r.calibration for r in kept.sessions() if r.recording_path == str(monday))


def test_a_rival_another_batch_stores_mid_run_is_caught_at_commit(fleet, tmp_path):
    """Two batches on one store: a recording claiming a module's session, stored by another process after this batch
    looked at the store and before it commits that module, makes its session a duplicate all the same."""
    folder, truth = fleet
    first, own = _clean(truth, 0), _clean(truth, 1)
    real = folder / "line" / own["file"]
    fake = _relabel(folder / "line" / _clean(truth, 2)["file"], real, tmp_path / "copied_header.csv")
    path = tmp_path / "s.sqlite"

    def other_batch(line):  # after the first session's commit, before the second's
        if line.startswith("[1/2]"):
            with Store(path) as other:
                run_batch([fake], load_spec(), other, toolkit_version="t", workers=0)

    with Store(path) as store:
        summary = run_batch([folder / "line" / first["file"], real], load_spec(), store, toolkit_version="t",
                            workers=0, progress=other_batch)
        rows = {r.recording_path: r for r in store.sessions(module_id=own["module_id"])}
    assert rows[str(fake)].status == "accepted"  # the other batch saw no rival when it stored
    assert rows[str(real)].status == "rejected" and rows[str(real)].reasons[0].startswith(
        f"duplicate module id '{own['module_id']}': 2 different recordings claim its session")
    assert summary.duplicates == {(own["module_id"], own["session_time"]): sorted([str(real), str(fake)])}
