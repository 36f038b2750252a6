"""``compass export CAL.json --format motioncal [--out FILE] [--port P]``: the calibration as the 68-byte
packet MotionCal sends and the PJRC/Adafruit sketches store (:mod:`compass.io.motioncal`).

The receiver computes ``B = W (m - V)`` on a magnetometer ``m`` in uT, with ``W`` symmetric: a hard
iron and a soft iron, nothing else.  A calibration is exported when its field is that form:

1. its sensor model is probed on the sphere of its own |B| (400 directions) and an affine map
   ``m -> B`` fitted (least squares); one that misses a probe by more than :data:`MAX_MISS` of |B|
   (0.06 deg of heading) is refused, with the miss: a four-flip or 3-D calibration with nonlinear
   channels, a table response;
2. the field is taken into the accelerometer's frame (the bench's ``mag_to_accel``, as the sketches'
   fusion expects) and the matrix split into a rotation times a symmetric matrix
   (``scipy.linalg.polar``): the symmetric part is ``W``; a rotation above ``--max-rotation-deg``
   is refused (the packet has no place for it), a smaller one is left out and said with its heading cost
   at the calibration's dip (:func:`compass.commands._export_form.left_out`: more than its angle, up to
   about ``angle (1 + tan dip)``), a reflection refused; an installed calibration's alignment (the product's yaw) is
   refused outright: the packet corrects the magnetometer in its own frame;
3. units: the receiver reads uT.  ``--unit`` names the unit of the calibration's readings (default
   uT); the field magnitude must then be the Earth's (12.5-130 uT, twice the World Magnetic Model's
   extremes) and ``W`` of order one (a bench calibration in volts is refused: the device would have
   to report volts).

The accelerometer zero-g and gyro zero-rate are sent as 0, as MotionCal sends them.  With ``--port``
the packet is written to the device and its ``Cal1:``/``Cal2:`` echoes are read for ``--wait``
seconds: the first echo of the values sent confirms it; echoes of other values only, no echo at all, or the
device lost while sending (the packet not confirmed) are said (exit 1: a slow or rounding echo may come from a
device that took it; a port that cannot be opened is exit 2).
"""

from __future__ import annotations

import contextlib
import math
import time

import numpy as np

__all__ = ["MAX_MISS", "packet_of", "run_motioncal", "send_packet"]

MAX_MISS = 1e-3
"""Largest miss of the affine form, as a fraction of |B| (1e-3: 0.06 deg of heading at most)."""
_EARTH_UT = (12.5, 130.0)
_UNITS = {"uT": "uT", "nT": "nT", "gauss": "G", "mgauss": "mG"}


def _fibonacci_sphere(n: int) -> np.ndarray:
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    phi = np.pi * (1.0 + 5.0 ** 0.5) * k
    r = np.sqrt(1.0 - z * z)
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


def packet_of(cal, *, unit: str = "uT", max_rotation_deg: float = 1.0, axes=None):
    """The packet of a calibration and notes on what it leaves out (module docstring).

    Parameters
    ----------
    cal : compass.calibration.Calibration
        The calibration (:func:`compass.commands.export.read_calibration`); errors name its ``path``.
    unit : {"uT", "nT", "gauss", "mgauss"}
        Unit of the calibration's magnetometer readings.
    max_rotation_deg : float
        Largest rotation between the corrected field and the accelerometer's frame that is left out.
    axes : tuple of 3 str, optional
        ``--axes``: the channels the device reads as its sensor's x, y, z; default from their names
        (:func:`compass.commands._export_form.axis_order`).

    Returns
    -------
    packet : compass.io.motioncal.CalPacket
    notes : list of str

    Raises
    ------
    compass.cli.BadInput
        The packet cannot hold the calibration: why, in one line.
    """
    from scipy.linalg import polar
    from scipy.spatial.transform import Rotation

    from ..cli import BadInput
    from ..io.motioncal import CalPacket
    from ..io.units import MAG_UNITS
    from ._export_form import axes_words, axis_order, left_out, rotation_words

    def refuse(why: str):
        return BadInput(f"{cal.path}: a {cal.kind} calibration cannot go into MotionCal's packet: {why}")

    model = cal.model
    if model is None or len(model.channels) != 3:
        n = 0 if model is None else len(model.channels)
        raise refuse(f"the packet holds three magnetometer axes, this sensor has {n} channel(s)"
                     + ("" if model is None else f" ({', '.join(model.channels)})"))
    alignment = None if cal.installation is None else cal.installation.alignment
    if alignment is not None:
        angle = Rotation.from_matrix(alignment).magnitude()
        raise refuse(f"its alignment turns the field {math.degrees(angle):.2f} deg into the product's frame, and the "
                     f"packet corrects the magnetometer in its own frame with no rotation: export the bench "
                     f"calibration it was installed from, or calibrate the installed module by a tumble")
    order = list(axis_order(cal, axes))
    magnitude = float(model.field_norm)
    field_b = magnitude * _fibonacci_sphere(400)
    x = field_b @ model.unit_directions.T
    raw = np.column_stack([r.output(x[:, c]) for c, r in enumerate(model.responses)])
    design = np.column_stack([field_b, np.ones(len(field_b))])
    coef, *_ = np.linalg.lstsq(design, raw, rcond=None)
    gain, offset = coef[:3].T, coef[3]  # raw = gain @ B + offset
    matrix = np.linalg.inv(gain)  # B = matrix (raw - offset)
    miss = float(np.max(np.linalg.norm((raw - design @ coef) @ matrix.T, axis=1))) / magnitude
    if miss > MAX_MISS:
        nonlinear = [c for c, r in zip(model.channels, model.responses) if r.model != "linear"]
        raise refuse(f"a matrix and an offset miss its field by up to {100 * miss:.2g} % of |B| "
                     f"({math.degrees(math.atan(miss)):.2g} deg of heading)"
                     + (f": channel(s) {', '.join(nonlinear)} have a nonlinear response" if nonlinear else ""))
    if all(r.model == "linear" for r in model.responses):  # the same map, exactly: no fit's rounding in the bytes
        offset = model.zero_outputs
        matrix = np.linalg.inv(model.gains[:, None] * model.unit_directions)
    matrix, offset = matrix[:, order], offset[order]  # the device's x, y, z in
    if cal.tumble is not None and cal.tumble.mag_to_accel is None:  # out, the sensor's own frame: in that order too
        matrix = matrix[order]
    to_model = cal.imu.rotation  # R_model<-accel: the bench's mag_to_accel (an installed alignment was refused)
    in_accel = matrix if to_model is None else to_model.T @ matrix
    rotation, soft = polar(in_accel, side="right")
    rotation_note = left_out(cal, rotation, axes=axes_words(cal, order, axes), max_rotation_deg=max_rotation_deg,
                             what=rotation_words(cal), form="MotionCal's packet")
    per_ut = MAG_UNITS[_UNITS[unit]]
    if cal.kind == "tumble":
        field_per_ut = per_ut  # a tumble's field is in its recording's unit
    elif model.field_ut is not None:
        field_per_ut = model.field_ut / magnitude
    else:
        raise refuse("its field is in units of the bench's |B| (no field_ut): the packet is in uT; recalibrate with "
                     "--field-ut")
    field_ut = magnitude * field_per_ut
    lo, hi = _EARTH_UT
    if not lo <= field_ut <= hi:
        fits = [u for u, key in _UNITS.items()
                if lo <= magnitude * (MAG_UNITS[key] if cal.kind == "tumble" else field_per_ut) <= hi]
        raise refuse(f"its |B| is {field_ut:.4g} uT with the readings in {unit}, not the Earth's field"
                     + (f": are they in {fits[0]} (--unit {fits[0]})?" if fits and cal.kind == "tumble" else ""))
    soft_ut = soft * field_per_ut / per_ut
    scale = float(np.cbrt(np.linalg.det(soft_ut)))
    if not 0.5 <= scale <= 2.0:
        raise refuse(f"its soft iron would scale the device's uT by {scale:.3g}: its readings are not in {unit} "
                     f"(volts, counts?), and the receiver reads the magnetometer in uT")
    notes = [axes_words(cal, order, axes), "accelerometer zero-g and gyro zero-rate sent as 0, as MotionCal sends them"]
    if rotation_note:
        notes.append(f"left out: {rotation_note}")
    if miss > 1e-6:
        notes.append(f"the matrix and offset reproduce the calibration to {100 * miss:.2g} % of |B|")
    if model.temperature is not None:
        notes.append("left out: the temperature effect (the packet holds the field at the reference temperature)")
    packet = CalPacket(np.zeros(3), np.zeros(3), offset * per_ut, field_ut, soft_ut)
    return packet, notes


def describe(packet, comments=()) -> str:
    """The sixteen numbers and the bytes, as text, after ``comments`` (lines of words, each written as ``# ...``)."""
    from ..io.motioncal import encode_packet

    s = packet.soft_iron
    data = encode_packet(packet)
    return ("# compass export: MotionCal calibration packet (68 bytes: 117, 84, 16 little-endian floats, CRC-16)\n"
            + "".join(f"# {line}\n" for line in comments)
            + f"hard_iron_ut {' '.join(f'{v:.6g}' for v in packet.hard_iron_ut)}\n"
            f"field_ut {packet.field_ut:.6g}\n"
            + "".join(f"soft_iron {' '.join(f'{v:.6g}' for v in row)}\n" for row in s)
            + "bytes " + data.hex(" ") + "\n")


try:
    import termios

    _TERMIOS_ERRORS = (termios.error,)
    """What a serial port's drain and flush raise on a device gone (EIO), not an OSError (POSIX only)."""
except ImportError:  # Windows
    _TERMIOS_ERRORS = ()


def send_packet(port: str, packet, *, baud: int = 115200, wait_s: float = 5.0) -> tuple[int, str]:
    """Write the packet to ``port`` and read the device's echoes for up to ``wait_s`` seconds.

    Returns
    -------
    status : int
        0: an echo of the values sent came; 1: only echoes of other values came, or none, or the device was lost
        while sending (not confirmed).
    words : str
    """
    import serial

    from ..cli import BadInput
    from ..io.fixed_lines import MotionCalDecoder
    from ..io.motioncal import echo_matches, encode_packet

    data = encode_packet(packet)
    try:
        link = serial.serial_for_url(port, baudrate=baud, timeout=0.05)
    except (serial.SerialException, OSError, ValueError) as exc:
        raise BadInput(f"cannot open port {port} ({str(exc).strip() or type(exc).__name__})") from None
    decoder, last, seen = MotionCalDecoder(("mx", "my", "mz")), None, 0
    try:
        link.reset_input_buffer()
        link.write(data)
        link.flush()
        deadline = time.monotonic() + wait_s
        while time.monotonic() < deadline:
            decoder.feed(link.read(4096))
            echo = (decoder.echo.get("Cal1"), decoder.echo.get("Cal2"))
            if echo[0] is None or echo[1] is None or echo is last:
                continue
            if last is not None and all(np.array_equal(a, b) for a, b in zip(echo, last)):
                continue
            last, seen = echo, seen + 1
            ok, words = echo_matches(packet, *echo)
            if ok:
                return 0, f"sent {len(data)} bytes to {port}; the device echoes the values sent (Cal1/Cal2: {words})"
            decoder.echo = {}  # wait for the next pair: an echo may have left before the packet arrived
    except (serial.SerialException, OSError, *_TERMIOS_ERRORS) as exc:  # a device lost, not bad input: exit 1
        return 1, (f"port {port}: {str(exc).strip() or type(exc).__name__} while sending the packet: the device was "
                   f"lost (unplugged?); not confirmed that it took the packet")
    finally:
        with contextlib.suppress(serial.SerialException, OSError, *_TERMIOS_ERRORS):
            link.close()
    if seen == 0:
        return 1, (f"sent {len(data)} bytes to {port}; no Cal1:/Cal2: echo in {wait_s:g} s: not confirmed that the "
                   f"device took it (a sketch that echoes prints them every second or so: check the port and --baud, "
                   f"or wait longer with --wait)")
    _, words = echo_matches(packet, *last)
    return 1, (f"sent {len(data)} bytes to {port}; for {wait_s:g} s the device echoes other values ({words}): not "
               f"confirmed that it took the packet (a sketch that echoes late or to fewer decimals may have: --wait "
               f"longer, or read its Cal1:/Cal2: lines; one without MotionCal's receiver never takes it)")


def run_motioncal(cal, *, out, force: bool, port, unit: str, max_rotation_deg: float, baud: int,
                 wait_s: float, inputs=(), axes=None, warnings=()) -> int:
    """The ``--format motioncal`` branch of ``compass export``: the packet of ``cal`` written to ``out``
    (refused if it exists, unless ``force``, and if it is one of ``inputs``), sent to ``port``, or else described on
    stdout (after ``warnings``, the calibration's own, as comments)."""
    import sys

    from ..io.atomic import atomic_open, check_writable
    from ..io.motioncal import encode_packet

    packet, notes = packet_of(cal, unit=unit, max_rotation_deg=max_rotation_deg, axes=axes)
    for note in notes:
        print(f"compass export: note: {note}", file=sys.stderr)
    if out:
        out = check_writable(out, force, inputs=inputs)
        with atomic_open(out, "wb") as f:
            f.write(encode_packet(packet))
        print(f"wrote {out} ({len(encode_packet(packet))} bytes)")
    if port:
        status, words = send_packet(port, packet, baud=baud, wait_s=wait_s)
        print(f"compass export: {words}", file=sys.stderr if status else sys.stdout)
        return status
    if not out:
        from ._export_form import axes_words, axis_order

        print(describe(packet, [axes_words(cal, axis_order(cal, axes), axes)]
                       + [f"warning: the calibration warns: {w}" for w in warnings]), end="")
    return 0
