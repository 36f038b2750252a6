"""``compass export --format fusion`` compiled against x-io Fusion's real headers (tests/data/fusion/, see
tests/data/README.md) and run through the release's own calibration function."""

import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from compass.cli import main
from tests._paths import TEST_DATA

HEADERS = TEST_DATA / "fusion"
RELEASES = ("1.2.0", "1.2.11", "1.3.0", "1.3.3")
"""The first and last release of each line the export claims (``--fusion-api 1.2`` and ``1.3``)."""
FUNCTION = re.compile(r"\b(Fusion\w*Magnetic)\(")
RAW = np.array([[0.0, 0.0, 0.0], [31.5, -12.25, 40.0], [-48.0, 7.5, -3.125]])
"""Uncalibrated magnetometer readings fed to the compiled calibration (recording units)."""

PROGRAM = """#include <stdio.h>
#include "Fusion.h"
#include "cal.h"
int main(void) {{
    const float raw[3][3] = {{{raw}}};
    for (int i = 0; i < 3; i++) {{
        const FusionVector uncalibrated = {{.axis = {{raw[i][0], raw[i][1], raw[i][2]}}}};
        const FusionVector calibrated = {function}(uncalibrated, softIronMatrix, hardIronOffset);
        printf("%.9g %.9g %.9g\\n", calibrated.axis.x, calibrated.axis.y, calibrated.axis.z);
    }}
    return 0;
}}
"""

COMPILERS = {"c": ["gcc", "-std=c99", "-pedantic"], "c++": ["g++", "-std=c++20", "-x", "c++"]}
"""C as firmware compiles it; C++20 (designated initialisers) as an Arduino sketch would."""


def calibration(tmp_path: Path, rotated: bool) -> tuple[Path, np.ndarray, np.ndarray]:
    """A tumble calibration file with a non-diagonal soft iron; returns it, its matrix for Fusion and offset."""
    rng = np.random.default_rng(3)
    soft = np.eye(3) + 0.05 * (lambda a: a + a.T)(rng.normal(size=(3, 3)))
    hard = np.array([1.5, -2.25, 0.125])
    rotation = np.eye(3)[[1, 2, 0]] if rotated else None
    doc = {"format": "compass-calibration/1", "model": "tumble", "hard_iron": hard.tolist(),
           "soft_iron": soft.tolist(), "field_norm": 50.0, "field_ut": 50.0, "dip_deg": 60.0,
           "noise_floor": [0.3] * 3, "mag_to_accel": None if rotation is None else rotation.tolist()}
    path = tmp_path / "cal.json"
    path.write_text(json.dumps(doc))
    return path, soft if rotation is None else rotation @ soft, hard


def build(tmp_path: Path, release: str, function: str, language: str) -> subprocess.CompletedProcess:
    raw = ", ".join("{" + ", ".join(f"{float(v)!r}f" for v in row) + "}" for row in RAW)
    source = tmp_path / "main.c"
    source.write_text(PROGRAM.format(raw=raw, function=function))
    return subprocess.run([*COMPILERS[language], "-Wall", "-Wextra", "-Werror", f"-I{HEADERS / release}",
                           f"-I{tmp_path}", str(source), "-o", str(tmp_path / "main"), "-lm"],
                          capture_output=True, text=True, timeout=120, cwd=tmp_path)


def export(tmp_path: Path, cal: Path, api: str | None) -> str:
    out = tmp_path / "cal.h"
    args = ["export", str(cal), "--format", "fusion", "--out", str(out), "--force"]
    assert main(args + (["--fusion-api", api] if api else [])) == 0
    return out.read_text()


def test_every_release_claimed_has_its_headers():
    for release in RELEASES:
        assert (HEADERS / release / "Fusion.h").is_file() and (HEADERS / release / "LICENSE.md").is_file()
    assert "float array[9];" in (HEADERS / "1.3.3" / "FusionMath.h").read_text()
    assert "float array[3][3];" in (HEADERS / "1.2.11" / "FusionMath.h").read_text()


@pytest.mark.skipif(shutil.which("gcc") is None or shutil.which("g++") is None, reason="no C/C++ compiler")
@pytest.mark.parametrize("language", sorted(COMPILERS))
@pytest.mark.parametrize("rotated", [False, True], ids=["plain", "mag_to_accel"])
@pytest.mark.parametrize("release", RELEASES)
def test_the_export_compiles_against_the_release_and_its_function_calibrates(tmp_path, release, rotated, language):
    """Compiled against the release's headers with every warning an error, the function the export names
    turns raw readings into soft_iron @ (raw - hard_iron), to float precision."""
    cal, matrix, hard = calibration(tmp_path, rotated)
    text = export(tmp_path, cal, release[:3])
    names = set(FUNCTION.findall(text))
    assert len(names) == 1, text
    (function,) = names
    done = build(tmp_path, release, function, language)
    assert done.returncode == 0, done.stderr
    run = subprocess.run([str(tmp_path / "main")], capture_output=True, text=True, timeout=60)
    got = np.array(run.stdout.split(), dtype=float).reshape(3, 3)
    np.testing.assert_allclose(got, (RAW - hard) @ matrix.T, rtol=1e-5, atol=1e-4)


@pytest.mark.skipif(shutil.which("gcc") is None, reason="no C compiler")
@pytest.mark.parametrize(("api", "other"), [("1.3", "1.2.11"), ("1.2", "1.3.0")])
def test_the_function_named_for_one_line_is_absent_from_the_other(tmp_path, api, other):
    """Why the flag exists: 1.3 renamed the function, so an export for one line does not build against the
    other (the matrix initialiser itself is the same text for both)."""
    cal, _, _ = calibration(tmp_path, False)
    (function,) = set(FUNCTION.findall(export(tmp_path, cal, api)))
    done = build(tmp_path, other, function, "c")
    assert done.returncode != 0 and function in done.stderr


def test_the_default_is_the_current_release(tmp_path):
    cal, _, _ = calibration(tmp_path, False)
    assert set(FUNCTION.findall(export(tmp_path, cal, None))) == {"FusionModelMagnetic"}
