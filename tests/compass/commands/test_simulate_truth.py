"""Every simulator writes its truth the same way: ``<stem>.truth.json`` beside the recording, nothing else."""

import json

import pytest

from compass.cli import main
from compass.io.table import read_table

KINDS = {
    "fourflip": [],
    "platform3d": [],
    "tumble": ["--samples", "300"],
    "reference": [],
    "runtime": ["--samples", "50"],
    "installation": ["--kind", "runtime", "--samples", "50"],
    "installation-tumble": ["--samples", "300"],
}


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_the_truth_is_json_beside_the_recording(tmp_path, capsys, kind):
    out = tmp_path / "rec.csv"
    assert main(["simulate", kind.split("-")[0], "--out", str(out), *KINDS[kind]]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec.csv", "rec.truth.json"]
    assert str(tmp_path / "rec.truth.json") in capsys.readouterr().out  # the command names it
    truth = json.loads((tmp_path / "rec.truth.json").read_text())
    if kind in ("runtime", "installation"):  # true angles per row, under the same keys for both
        rows = len(read_table(out).column("t_s"))
        assert all(len(truth[k]) == rows for k in ("heading_deg", "pitch_deg", "roll_deg"))
