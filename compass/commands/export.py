"""``compass export CAL.json --format fusion|ardupilot|motioncal``: a calibration in firmware terms.

``motioncal`` (the 68-byte packet the PJRC/Adafruit sketches store, written or sent to a port) is
:mod:`compass.commands._export_motioncal`.

A tumble calibration, or any three linear channels of the channel form (a bench calibration, an
installed one: :func:`channel_form`), as a matrix and an offset from raw counts to the field in H.

- ``fusion``: x-io Fusion's ``FusionModelMagnetic(uncalibrated, softIronMatrix, hardIronOffset)`` (1.3;
  ``FusionCalibrationMagnetic`` in 1.2, ``--fusion-api 1.2``) computes
  ``softIronMatrix * (uncalibrated - hardIronOffset)``, the same form as the calibration file;
  the magnetometer-to-accelerometer rotation, when fitted (a tumble's, or a bench calibration's
  ``mag_to_accel`` from its recording's accelerometer), is folded into the matrix
  (``C @ soft_iron``) because Fusion expects the magnetometer in the sensor (accelerometer) frame.
  The initialisers name the union members (``{.element = {.xx = 1.0f, ...}}``): 1.3's ``FusionMatrix``
  is ``float array[9]``, 1.2's ``array[3][3]``, both with the ``element`` struct, so one text compiles
  against either, as C99 and C++20 with every warning an error (tests/compass/commands/test_export_fusion.py
  builds it against the real headers of 1.2.0, 1.2.11, 1.3.0 and 1.3.3 and runs the release's function).
- ``ardupilot``: AP_Compass adds ``COMPASS_OFS`` then multiplies by the symmetric matrix of
  ``COMPASS_DIA`` (diagonal) and ``COMPASS_ODI`` (xy, xz, yz), in milligauss.  So
  ``OFS = -hard_iron`` converted to milligauss and the matrix is the soft iron's shape (det 1).
  ArduPilot has no parameter for a rotation: one up to ``--max-rotation-deg`` (default 1 deg) is left out
  and its heading cost at the calibration's dip said (:func:`compass.commands._export_form.left_out`), a
  larger one or a reflection refused.

Every format takes the channels in the order the firmware reads its sensor, x, y, z
(:func:`compass.commands._export_form.axis_order`).
"""

from __future__ import annotations

import sys

import numpy as np

from .. import limits
from ..io.atomic import atomic_write_text, check_writable
from ..io.units import EARTH_FIELD_UT, MAG_UNITS
from ._export_form import warnings_of

__all__ = ["register", "export_text", "firmware_form", "read_calibration", "channel_form", "unit_note"]

FORMATS = ("fusion", "ardupilot", "motioncal")
FUSION_FUNCTIONS = {"1.3": "FusionModelMagnetic", "1.2": "FusionCalibrationMagnetic"}
"""Fusion's magnetometer calibration function by release (1.3 renamed it and made FusionMatrix a flat
``float array[9]``)."""
_UNITS = {"uT": "uT", "nT": "nT", "gauss": "G", "mgauss": "mG"}
"""``--unit`` spellings -> :data:`compass.io.units.MAG_UNITS` (their factors to uT)."""


def register(sub) -> None:
    p = sub.add_parser("export", help="write a calibration as firmware parameters (x-io Fusion, ArduPilot) or send "
                                      "it to a MotionCal sketch")
    p.add_argument("calibration", nargs="?", help="calibration JSON written by 'compass calibrate': tumble, or three "
                                                  "linear channels (bench, installed)")
    p.add_argument("--module", metavar="ID", help="instead of a file: the module's calibration in --store, from its "
                                                 "latest session, refused unless that is accepted (without "
                                                 "--format: the calibration file itself)")
    p.add_argument("--store", metavar="PATH", help="with --module: the calibration store (compass batch)")
    p.add_argument("--session", metavar="TIME", help="with --module: the module's session at TIME (as 'compass store "
                                                     "show' lists it, or any ISO form of that instant) instead of its "
                                                     "latest: an earlier accepted one, knowing a later one was not")
    p.add_argument("--format", choices=FORMATS,
                   help="fusion: C initialisers; ardupilot: .param lines; motioncal: the 68-byte packet MotionCal "
                        "sends (to --out, or to the device on --port)")
    p.add_argument("--unit", choices=tuple(_UNITS), default=None,
                   help="unit of the recording's mx,my,mz (ardupilot offsets are in milligauss; fusion and motioncal "
                        "check the field against it; default uT)")
    p.add_argument("--fusion-api", choices=tuple(FUSION_FUNCTIONS), default=None,
                   help="fusion: the Fusion release line (1.3, the default: FusionModelMagnetic, as imufusion 1.3; "
                        "1.2: FusionCalibrationMagnetic); compile-tested against 1.2.0, 1.2.11, 1.3.0 and 1.3.3")
    p.add_argument("--axes", metavar="CX,CY,CZ", default=None,
                   help="the calibration's channels the firmware reads as its sensor's x, y, z, in that order "
                        "(default: from the names: mx,my,mz, x,y,z, mag_x..; names that say no axis, a bench's v1,v2,v3: "
                        "their column order, said in the output)")
    p.add_argument("--max-rotation-deg", type=limits.Range(0.0, 180.0, "deg").option("--max-rotation-deg"),
                   default=None,
                   help="ardupilot, motioncal: largest rotation between the sensor's axes and the accelerometer's "
                        "(the housing's without one) left out of the symmetric matrix, which cannot hold one (default "
                        "1 deg); its heading cost at the calibration's dip is said, a larger one refused (fusion "
                        "folds it in)")
    p.add_argument("--out", default=None, help="file to write (default: print)")
    p.add_argument("--force", action="store_true",
                   help="overwrite --out; export a calibration whose own warnings say its numbers are not to be used "
                        "(a fit that did not converge, a part not determined) all the same")
    m = p.add_argument_group("motioncal")
    m.add_argument("--port", help="send the packet to the device on this serial port (pyserial URL) and read back its "
                                  "Cal1:/Cal2: echo")
    m.add_argument("--baud", type=limits.BAUD.option("--baud"), default=None, help="with --port: baud rate (default "
                                                                                   "115200)")
    m.add_argument("--wait", type=limits.DURATION_S.option("--wait"), default=None, metavar="S",
                   help="with --port: how long to wait for the device's echo of the values sent (default 5 s)")
    p.set_defaults(func=run)


OUTPUT_UNITS_NOTE = ("a bench calibration's offsets are its channels' zero-field outputs in the recording's output "
                     "unit (volts, counts), not a field: COMPASS_OFS (milligauss) and the --unit conversion hold only "
                     "if the module's channels read field units")


DEFAULTS = {"unit": "uT", "fusion_api": "1.3", "baud": 115200, "wait": 5.0, "max_rotation_deg": 1.0}
"""Values of the options not given (argparse leaves them None, so one given where it does nothing is refused)."""
_OPTION_FOR = {"unit": "--format fusion, ardupilot or motioncal", "fusion_api": "--format fusion",
               "port": "--format motioncal", "baud": "--format motioncal with --port",
               "wait": "--format motioncal with --port", "max_rotation_deg": "--format ardupilot or motioncal"}
"""What each format-specific option is for, in words."""


def run(args) -> int:
    from ..cli import BadInput

    if (args.module is None) == (args.calibration is None):
        raise BadInput("give a calibration file or --module ID --store PATH (one of them)")
    if args.session is not None and args.module is None:
        raise BadInput("--session picks a session of --module ID in --store; a calibration file has none")
    if args.format is None and args.module is None:
        raise BadInput("--format is required with a calibration file (fusion, ardupilot or motioncal)")
    _refuse_unused(args)
    if args.module is None:
        cal = read_calibration(args.calibration)
    else:
        text, name = _stored(args)
        if args.format is None:
            _emit(args, text)
            return 0
        cal = _parse(text, name)
    option = {dest: DEFAULTS[dest] if getattr(args, dest) is None else getattr(args, dest) for dest in DEFAULTS}
    axes = _axes(args.axes)
    warnings = warnings_of(cal, force=args.force)
    for words in warnings:
        print(f"compass export: warning: {cal.path}: the calibration warns: {words}", file=sys.stderr)
    if args.format == "motioncal":
        from ._export_motioncal import run_motioncal

        return run_motioncal(cal, out=args.out, force=args.force, inputs=(args.calibration,), port=args.port,
                             unit=option["unit"], axes=axes, warnings=warnings,
                             max_rotation_deg=option["max_rotation_deg"], baud=option["baud"], wait_s=option["wait"])
    form = firmware_form(cal, axes) | {"warnings": warnings}
    if args.format == "ardupilot":
        form["left_out"] = _left_out_by_ardupilot(cal, form, option["max_rotation_deg"])
    note = unit_note(form, option["unit"])
    if note:
        print(f"compass export: warning: {cal.path}: {note}", file=sys.stderr)
    if form.get("output_units") and args.format == "ardupilot":
        print(f"compass export: warning: {cal.path}: {OUTPUT_UNITS_NOTE}", file=sys.stderr)
    _emit(args, export_text(form, args.format, unit=option["unit"], fusion_api=option["fusion_api"]))
    return 0


def _axes(text):
    """``--axes`` as three names, or None; BadInput for a malformed one."""
    from ..cli import BadInput
    from ._export_form import parse_axes

    try:
        return None if text is None else parse_axes(text)
    except ValueError as exc:
        raise BadInput(f"--axes: {exc}") from None


def _left_out_by_ardupilot(cal, form: dict, max_rotation_deg: float) -> str | None:
    """Words for the rotation ArduPilot's symmetric matrix leaves out (said on stderr), None for none; BadInput for
    one above ``max_rotation_deg`` or a reflection (:func:`compass.commands._export_form.left_out`)."""
    from ._export_form import left_out, rotation_words

    if form["mag_to_accel"] is None:
        return None
    words = left_out(cal, form["mag_to_accel"], axes=form["axes"], max_rotation_deg=max_rotation_deg,
                     what=rotation_words(cal), form="ArduPilot's COMPASS_* parameters")
    if words:
        print(f"compass export: note: left out: {words}", file=sys.stderr)
    return words


def _refuse_unused(args) -> None:
    """BadInput for a format-specific option given where it does nothing (:data:`_OPTION_FOR`)."""
    from ..cli import BadInput

    used = {"fusion": {"unit", "fusion_api"}, "ardupilot": {"unit", "max_rotation_deg"}, None: set(),
            "motioncal": {"unit", "max_rotation_deg", "port"} | ({"baud", "wait"} if args.port else set())}
    for dest, what in _OPTION_FOR.items():
        if getattr(args, dest) is not None and dest not in used[args.format]:
            option = "--" + dest.replace("_", "-")
            context = f"--format {args.format}" if args.format else "no --format (the stored file is written as it is)"
            if args.format == "motioncal" and dest in ("baud", "wait"):
                context += " without --port (nothing is sent)"
            raise BadInput(f"{option} is for {what}; it does nothing with {context}")


def _stored(args) -> tuple[str, str]:
    """``--module ID --store PATH [--session TIME]``: the calibration's text and what to call it."""
    from ..cli import BadInput
    from ..production.store import SessionTimeError, Store, StoreError

    if args.store is None:
        raise BadInput("--module needs --store PATH (the calibration store compass batch wrote)")
    try:
        with Store(args.store, create=False) as store:
            row = store.exportable(args.module, args.session)
    except SessionTimeError as exc:
        raise BadInput(f"--session {exc}") from None
    except StoreError as exc:
        raise BadInput(str(exc)) from None
    print(f"compass export: module {row.module_id}, session {row.session_time} (accepted; recording "
          f"{row.recording_path})", file=sys.stderr)
    return row.calibration, f"module {row.module_id} in {args.store}"


def _emit(args, text: str) -> None:
    if args.out:
        out = check_writable(args.out, args.force, inputs=(args.calibration,))
        atomic_write_text(out, text)
        print(f"wrote {out}")
    else:
        print(text, end="")


def read_calibration(path):
    """:func:`compass.calibration.load`, a file's error as BadInput (exit 2, one line naming the file)."""
    from ..calibration import load
    from ..cli import BadInput

    try:
        return load(path)
    except ValueError as exc:
        raise BadInput(str(exc) if str(path) in str(exc) else f"{path}: {exc}") from None


def _parse(text: str, name: str):
    """A stored calibration's text as :func:`read_calibration` reads a file, its errors naming ``name``."""
    from ..calibration import loads
    from ..cli import BadInput

    try:
        return loads(text, name=name)
    except ValueError as exc:
        raise BadInput(str(exc) if name in str(exc) else f"{name}: {exc}") from None


def firmware_form(cal, axes=None) -> dict:
    """A calibration (:class:`compass.calibration.Calibration`) in firmware terms; BadInput (exit 2) else.

    Parameters
    ----------
    cal : compass.calibration.Calibration
    axes : tuple of 3 str, optional
        ``--axes``: the channels the firmware reads as its sensor's x, y, z; default from their names
        (:func:`compass.commands._export_form.axis_order`).

    Returns
    -------
    dict
        ``hard_iron`` (3,), ``soft_iron`` (3, 3), ``mag_to_accel`` (3, 3) or None, numpy arrays
        (validated: finite, soft iron symmetric positive definite), in the firmware's x, y, z order:
        ``mag_to_accel @ soft_iron @ (raw - hard_iron)`` is the field in the accelerometer's frame (the
        housing's without one) for ``raw`` the sensor's ``(x, y, z)``; ``axes`` (the words for the
        order) and ``field_norm_recording_units`` (|B| in the recording's unit, float or None).
    """
    from ..cli import BadInput
    from ._export_form import axes_words, axis_order

    if cal.tumble is None:
        try:
            check_channels(cal.model)
        except ValueError as exc:
            raise BadInput(f"{cal.path}: a {cal.kind} calibration cannot be exported: {exc}") from None
        order = axis_order(cal, axes)
        form = channel_form(cal.model, order)
        # the field in the accelerometer's frame, as Fusion fuses it: back from the model's frame (H, or an
        # installed file's product frame) through the bench's mag_to_accel and the installation's alignment
        to_model = cal.imu.rotation
        if to_model is not None:
            form["mag_to_accel"] = to_model.T @ form["mag_to_accel"]
        return form | {"axes": axes_words(cal, order, axes)}
    t = cal.tumble
    order = axis_order(cal, axes)
    form = {"hard_iron": t.hard_iron, "soft_iron": t.soft_iron, "mag_to_accel": t.mag_to_accel,
            "field_norm_recording_units": t.field_norm_recording_units, "axes": axes_words(cal, order, axes)}
    if order != (0, 1, 2):  # the sensor's x, y, z in: its columns; out, the accelerometer's frame, else the sensor's
        if t.mag_to_accel is None:  # own, in the same order: its rows too (P S P^T, symmetric)
            form |= _split(t.soft_iron[np.ix_(order, order)], t.hard_iron[list(order)])
        else:
            form |= _split(t.mag_to_accel @ t.soft_iron[:, order], t.hard_iron[list(order)])
    return form


def check_channels(model) -> None:
    """ValueError unless the model is three linear channels (what a matrix and an offset reproduce)."""
    from ..response import LinearResponse

    if len(model.channels) != 3:
        raise ValueError(f"firmware takes three axes; this sensor has {len(model.channels)} channels "
                         f"({', '.join(model.channels)})")
    nonlinear = [c for c, r in zip(model.channels, model.responses) if not isinstance(r, LinearResponse)]
    if nonlinear:
        raise ValueError(f"channel(s) {', '.join(nonlinear)} have a nonlinear response, which a matrix and an offset "
                         f"cannot reproduce: export is for linear channels")


def channel_form(model, order=(0, 1, 2)) -> dict:
    """The firmware form of a channel-form model (bench or installed): ``raw = o + G B_H``, so
    ``B_H = G^-1 (raw - o)`` with ``G = diag(gain) A`` (rows: each channel's gain times its direction),
    its rows taken in ``order`` (the channels the firmware reads as x, y, z).

    ``G^-1`` is split into a rotation times a symmetric matrix (:func:`_split`): the symmetric part is
    the soft iron, the rotation goes where the tumble's magnetometer-to-accelerometer rotation goes
    (folded in for Fusion, left out by ArduPilot).

    Raises
    ------
    ValueError
        Not three channels, or a nonlinear response (no matrix and offset reproduce it).
    """
    check_channels(model)
    rows = list(order)
    form = _split(np.linalg.inv(model.gains[rows, None] * model.unit_directions[rows]), model.zero_outputs[rows])
    return form | {"field_norm_recording_units": None, "output_units": True}


def _split(matrix: np.ndarray, offset: np.ndarray) -> dict:
    """``matrix (raw - offset)`` as ``mag_to_accel @ soft_iron @ (raw - hard_iron)``: the polar decomposition
    (``scipy.linalg.polar``), the symmetric part the soft iron.  ``mag_to_accel`` is orthogonal; its
    determinant is -1 when the sensor's x, y, z are a left-handed set against the field's frame."""
    from scipy.linalg import polar

    rotation, soft = polar(matrix, side="right")
    return {"hard_iron": offset, "soft_iron": soft, "mag_to_accel": rotation}


def unit_note(cal: dict, unit: str) -> str:
    """Words for a field norm that is not Earth's in ``unit`` (25-65 uT), else "".

    The hard-iron offsets are in the recording's unit; exported as ``unit`` they are wrong by the
    unit's factor when the recording was in another one.
    """
    norm = cal.get("field_norm_recording_units")
    if norm is None:
        return ""
    lo, hi = EARTH_FIELD_UT
    ut = norm * MAG_UNITS[_UNITS[unit]]
    if lo <= ut <= hi:
        return ""
    fits = [u for u, key in _UNITS.items() if lo <= norm * MAG_UNITS[key] <= hi]
    hint = f"; the recording looks like it is in {' or '.join(fits)} (--unit {fits[0]})" if fits else ""
    return (f"its field norm is {norm:.4g} in the recording's unit, which as {unit} would be {ut:.4g} uT, not "
            f"Earth's {lo:g}-{hi:g} uT: the offsets are exported as {unit} all the same{hint}")


def export_text(cal: dict, fmt: str, *, unit: str = "uT", fusion_api: str = "1.3") -> str:
    """Firmware text for a calibration's firmware form.

    Parameters
    ----------
    cal : dict
        ``hard_iron`` (3,), ``soft_iron`` (3, 3), ``mag_to_accel`` (3, 3) or None, as numpy arrays
        (:func:`firmware_form`); optional ``field_norm_recording_units`` for the unit check, ``axes`` (the
        channels read as x, y, z, in words), ``warnings`` (the calibration's own) and ``left_out`` (ArduPilot: the
        rotation it leaves out and its heading cost, in words) for the comments.
    fmt : {"fusion", "ardupilot"}
    unit : str
        Recording unit of the magnetometer (ArduPilot only).
    fusion_api : {"1.3", "1.2"}
        The Fusion release whose calibration function the comment names (:data:`FUSION_FUNCTIONS`);
        the initialisers are the same for both.

    Returns
    -------
    str
    """
    h, s, c = cal["hard_iron"], cal["soft_iron"], cal["mag_to_accel"]
    if fmt == "fusion":
        m = s if c is None else c @ s
        note = "" if c is None else " (mag-to-accel rotation folded in)"
        unit_line = f"// warning: {unit_note(cal, unit)}\n" if unit_note(cal, unit) else ""
        axes_line = f"// {cal['axes']}\n" if cal.get("axes") else ""
        axes_line += "".join(f"// warning: the calibration warns: {w}\n" for w in cal.get("warnings", ()))
        # designated members: Fusion 1.3's FusionMatrix is float array[9], 1.2's array[3][3]; both name
        # the elements xx..zz (row-major) and a vector's axis x, y, z, so one text compiles against either
        elements = ", ".join(f".{r}{col} = {c_float(m[i, j])}" for i, r in enumerate("xyz") for j, col in enumerate("xyz"))
        axes = ", ".join(f".{a} = {c_float(v)}" for a, v in zip("xyz", h))
        return (f"// compass export: x-io Fusion {fusion_api}, {FUSION_FUNCTIONS[fusion_api]}(magnetometer, "
                f"softIronMatrix, hardIronOffset){note}\n" + axes_line + unit_line +
                f"const FusionMatrix softIronMatrix = {{.element = {{{elements}}}}};\n"
                f"const FusionVector hardIronOffset = {{.axis = {{{axes}}}}};\n")
    shape = s / np.cbrt(np.linalg.det(s))
    ofs = -h * MAG_UNITS[_UNITS[unit]] / MAG_UNITS["mG"]  # ArduPilot's offsets are in milligauss
    lines = ["# compass export: ArduPilot COMPASS_* (offsets in milligauss, matrix = soft-iron shape, det 1)"]
    if cal.get("axes"):
        lines.append(f"# {cal['axes']}")
    lines += [f"# warning: the calibration warns: {w}" for w in cal.get("warnings", ())]
    if unit_note(cal, unit):
        lines.append(f"# warning: {unit_note(cal, unit)}")
    if cal.get("output_units"):
        lines.append(f"# warning: {OUTPUT_UNITS_NOTE}")
    if cal.get("left_out"):
        lines.append(f"# not exported (no ArduPilot parameter): {cal['left_out']}")
    lines += [f"COMPASS_OFS_{a},{v:.4f}" for a, v in zip("XYZ", ofs)]
    lines += [f"COMPASS_DIA_{a},{v:.6f}" for a, v in zip("XYZ", np.diag(shape))]
    lines += [f"COMPASS_ODI_{a},{v:.6f}" for a, v in zip("XYZ", (shape[0, 1], shape[0, 2], shape[1, 2]))]
    return "\n".join(lines) + "\n"


def c_float(v: float) -> str:
    """A C ``float`` literal of ``v`` (7 significant digits): ``1.0f``, ``-2.5e-05f``, never ``1f``."""
    text = f"{float(v):.7g}"
    if not np.isfinite(v):
        raise ValueError(f"cannot write {v} as a C float")
    return (text if any(ch in text for ch in ".e") else text + ".0") + "f"
