"""``compass calibrate INSTALL.csv --base BENCH.json --out INSTALLED.json [--site ...]``: the installation.

The bench-calibrated module turned inside its product (SPEC section 2's installation recording, a
tumble or a swing): the product's hard and soft iron in the housing frame on top of the bench model
(:mod:`calibrate.installation`), written as the installed calibration file (``"model": "installed"``,
the bench calibration whole under ``"base"``).
"""

from __future__ import annotations

import json
from pathlib import Path

from ..io.atomic import atomic_write_text, check_writable


def calibrate_installation_file(recording, base, out, *, site=None, date=None, diagnose=True, report=None,
                                force=False, quiet=False):
    """Calibrate an installation recording on top of the bench calibration file ``base``.

    Returns
    -------
    calibrate.installation.InstallationCalibration

    Raises
    ------
    RecordingError, BadInput, FileExistsError
        Bad input (exit status 2 on the command line).
    """
    from calibrate.installation import InstallationCalibrator, InstallationRefused

    from ..cli import BadInput
    from ..io.installation import read_installation
    from ..model import SensorModel
    from ..site import Site

    out = check_writable(out, force)
    if date is not None and site is None:
        raise BadInput("--date needs --site LAT,LON[,ALT_M]: the date only chooses the field at a site")
    try:
        site = None if site is None else Site.parse(site, date)
    except ValueError as exc:
        raise BadInput(str(exc)) from None
    if report is not None and Path(report).exists() and not Path(report).is_dir():
        raise BadInput(f"--report {report}: is a file, expected a folder")
    try:
        document = json.loads(Path(base).read_text(encoding="utf-8"))
        model = SensorModel.from_json(document)
    except OSError as exc:
        raise BadInput(f"{base}: cannot read calibration file ({exc.strerror})") from None
    except ValueError as exc:
        raise BadInput(f"{base}: {exc}") from None
    if document.get("model") == "installed":
        raise BadInput(f"{base}: already an installed calibration; give the bench calibration as --base")
    rec = read_installation(recording, model.channels)
    try:
        result = InstallationCalibrator(base=model, base_document=document, site=site, diagnose=diagnose).fit(rec)
    except InstallationRefused as exc:
        raise BadInput(str(exc)) from None
    if not quiet:
        print(result.report())
    atomic_write_text(out, json.dumps(result.to_json(), indent=2) + "\n")
    print(f"wrote {out}")
    if report is not None:
        for path in result.plots(report):
            print(f"wrote {path}")
    return result
