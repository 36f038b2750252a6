"""``compass export CAL.json --format fusion|ardupilot``: a tumble calibration in firmware terms.

- ``fusion``: x-io Fusion's ``FusionCalibrationMagnetic(uncalibrated, softIronMatrix, hardIronOffset)``
  computes ``softIronMatrix * (uncalibrated - hardIronOffset)``, the same form as the calibration file;
  the magnetometer-to-accelerometer rotation, when fitted, is folded into the matrix
  (``C @ soft_iron``) because Fusion expects the magnetometer in the sensor (accelerometer) frame.
- ``ardupilot``: AP_Compass adds ``COMPASS_OFS`` then multiplies by the symmetric matrix of
  ``COMPASS_DIA`` (diagonal) and ``COMPASS_ODI`` (xy, xz, yz), in milligauss.  So
  ``OFS = -hard_iron`` converted to milligauss and the matrix is the soft iron's shape (det 1).
  ArduPilot has no parameter for a small rotation; it is reported, not exported.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..io.atomic import atomic_write_text, check_writable

__all__ = ["register", "export_text"]

FORMATS = ("fusion", "ardupilot")
_MGAUSS_PER_UNIT = {"uT": 10.0, "nT": 0.01, "gauss": 1000.0, "mgauss": 1.0}


def register(sub) -> None:
    p = sub.add_parser("export", help="write a tumble calibration as firmware parameters (x-io Fusion, ArduPilot)")
    p.add_argument("calibration", help="calibration JSON written by 'compass calibrate' from a tumble recording")
    p.add_argument("--format", required=True, choices=FORMATS, help="fusion: C initialisers; ardupilot: .param lines")
    p.add_argument("--unit", choices=tuple(_MGAUSS_PER_UNIT), default="uT",
                   help="unit of the recording's mx,my,mz (ardupilot offsets are in milligauss; default uT)")
    p.add_argument("--out", default=None, help="file to write (default: print)")
    p.add_argument("--force", action="store_true", help="overwrite --out")
    p.set_defaults(func=run)


def run(args) -> int:
    text = export_text(load_tumble(args.calibration), args.format, unit=args.unit)
    if args.out:
        out = check_writable(args.out, args.force)
        atomic_write_text(out, text)
        print(f"wrote {out}")
    else:
        print(text, end="")
    return 0


def load_tumble(path) -> dict:
    """Read a tumble calibration file; BadInput (exit 2) for anything else."""
    from ..cli import BadInput

    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except OSError as exc:
        raise BadInput(f"{path}: cannot read file ({exc.strerror})") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise BadInput(f"{path}: not a JSON calibration file ({exc})") from None
    if not isinstance(data, dict) or data.get("format") != "compass-calibration/1":
        fmt = data.get("format") if isinstance(data, dict) else None
        raise BadInput(f"{path}: unknown calibration format {fmt!r}; expected 'compass-calibration/1'")
    if data.get("model") != "tumble":
        raise BadInput(f"{path}: export needs a tumble calibration (\"model\": \"tumble\"); this file is "
                       f"{data.get('model', 'a four-flip calibration')!r}")
    try:
        h = np.asarray(data["hard_iron"], dtype=float).reshape(3)
        s = np.asarray(data["soft_iron"], dtype=float).reshape(3, 3)
        c = None if data.get("mag_to_accel") is None else np.asarray(data["mag_to_accel"], float).reshape(3, 3)
    except (KeyError, TypeError, ValueError) as exc:
        raise BadInput(f"{path}: hard_iron must be 3 numbers, soft_iron and mag_to_accel 3x3 ({exc})") from None
    if not (np.all(np.isfinite(h)) and np.all(np.isfinite(s)) and np.linalg.det(s) > 0):
        raise BadInput(f"{path}: soft_iron must be finite with a positive determinant")
    return {"hard_iron": h, "soft_iron": s, "mag_to_accel": c}


def export_text(cal: dict, fmt: str, *, unit: str = "uT") -> str:
    """Firmware text for a tumble calibration.

    Parameters
    ----------
    cal : dict
        ``hard_iron`` (3,), ``soft_iron`` (3, 3), ``mag_to_accel`` (3, 3) or None, as numpy arrays.
    fmt : {"fusion", "ardupilot"}
    unit : str
        Recording unit of the magnetometer (ArduPilot only).

    Returns
    -------
    str
    """
    h, s, c = cal["hard_iron"], cal["soft_iron"], cal["mag_to_accel"]
    if fmt == "fusion":
        m = s if c is None else c @ s
        note = "" if c is None else " (mag-to-accel rotation folded in)"
        cells = ", ".join(f"{v:.7g}f" for v in m.ravel())
        return (f"// compass export: x-io Fusion, FusionCalibrationMagnetic(m, softIronMatrix, hardIronOffset){note}\n"
                f"const FusionMatrix softIronMatrix = {{{cells}}};\n"
                f"const FusionVector hardIronOffset = {{{', '.join(f'{v:.7g}f' for v in h)}}};\n")
    shape = s / np.cbrt(np.linalg.det(s))
    ofs = -h * _MGAUSS_PER_UNIT[unit]
    lines = ["# compass export: ArduPilot COMPASS_* (offsets in milligauss, matrix = soft-iron shape, det 1)"]
    if c is not None:
        angle = np.degrees(np.arccos(np.clip((np.trace(c) - 1.0) / 2.0, -1.0, 1.0)))
        lines.append(f"# not exported: magnetometer-to-accelerometer rotation of {angle:.2f} deg (no ArduPilot parameter)")
    lines += [f"COMPASS_OFS_{a},{v:.4f}" for a, v in zip("XYZ", ofs)]
    lines += [f"COMPASS_DIA_{a},{v:.6f}" for a, v in zip("XYZ", np.diag(shape))]
    lines += [f"COMPASS_ODI_{a},{v:.6f}" for a, v in zip("XYZ", (shape[0, 1], shape[0, 2], shape[1, 2]))]
    return "\n".join(lines) + "\n"
