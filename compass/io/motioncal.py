"""MotionCal's serial protocol: the ``Raw:``/``Uni:`` sample lines a calibration sketch prints, the
``Cal1:``/``Cal2:`` lines it echoes, and the 68-byte calibration packet it receives.

What the PJRC and Adafruit sketches send (read in their public sources)
-----------------------------------------------------------------------
PJRC ``NXPMotionSense/examples/CalibrateSensors/CalibrateSensors.ino`` prints the sensors' integer
counts, ``Raw:ax,ay,az,gx,gy,gz,mx,my,mz`` (``Serial.println``: ``\\r\\n``), whose units
``NXPMotionSense.h`` defines: ``G_PER_COUNT 0.0001220703125f // = 1/8192``,
``DEG_PER_SEC_PER_COUNT 0.0625f // = 1/16``, ``UT_PER_COUNT 0.1f``.  MotionCal's ``rawdata.c``
(``raw_data``) reads them with the same three constants, and its ``serialdata.c`` (``ascii_parse``)
takes exactly nine integers in ``int16`` range after ``Raw:``, ended by ``\\r``.

Adafruit ``Adafruit_AHRS/examples/calibration/calibration.ino`` scales its unified-sensor readings
to those counts and truncates: ``int(accel_m_s2 * 8192 / 9.8)``, ``int(gyro_rad_s *
SENSORS_RADS_TO_DPS * 16)``, ``int(mag_uT * 10)``; then prints the same sample unscaled as
``Uni:ax,ay,az,gx,gy,gz,mx,my,mz`` in m/s^2 (2 decimals), rad/s (4 decimals) and uT (2 decimals).
Its ``9.8`` (not 9.80665) makes ``Raw:`` accelerations 0.07 % large: a scale, so no direction changes.

Both sketches echo what they hold, every 50-100 samples: ``Cal1:`` ten numbers (accelerometer
zero-g x3, gyro zero-rate x3, magnetometer hard iron x3 in uT, field magnitude in uT; 3 decimals)
and ``Cal2:`` the soft-iron matrix, nine numbers row by row (4 decimals).

The calibration packet (MotionCal -> device)
--------------------------------------------
68 bytes: the signature ``117, 84``; sixteen IEEE-754 single floats, least significant byte first:
accelerometer zero-g (3), gyro zero-rate (3), magnetometer hard iron (3, uT), field magnitude (uT),
soft iron ``W[0][0], W[1][1], W[2][2], W[0][1], W[0][2], W[1][2]`` (the symmetric matrix's unique
entries); a CRC-16 of the first 66 bytes, least significant byte first.  The CRC starts at 0xFFFF
and runs the reflected polynomial 0xA001 (``crc = (crc >> 1) ^ 0xA001`` when the low bit is set), so
the receiver's CRC over all 68 bytes is 0.  Sources: the receiver ``receiveCalibration()`` of
``calibration.ino`` and ``CalibrateSensors.ino`` (signature, 68 bytes, ``crc == 0``, the float order
``offsets[0..15]`` with ``mag_softiron[1] = offsets[13]``, ``[2] = offsets[14]``, ``[5] = offsets[15]``),
``Adafruit_Sensor_Calibration.cpp`` (``crc16_update``, 0xA001) and
``Adafruit_Sensor_Calibration_EEPROM.cpp`` (``saveCalibration``: the same layout stored in EEPROM), and
MotionCal's ``send_calibration()`` (accelerometer and gyro offsets sent as 0, then ``magcal.V``,
``magcal.B``, ``invW`` in that order).  The receiver applies ``B = W (raw - V)``, the hard iron
subtracted first (``Adafruit_Sensor_Calibration::calibrate``), the same form as a tumble calibration
file.  The accelerometer offsets are in m/s^2 and the gyro's in rad/s in Adafruit's library
(``Adafruit_Sensor_Calibration.h``); MotionCal always sends both as 0.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

import numpy as np

from .units import STANDARD_GRAVITY

__all__ = ["G_PER_COUNT", "DEG_S_PER_COUNT", "UT_PER_COUNT", "PACKET_SIZE", "SIGNATURE", "CalPacket", "crc16",
           "encode_packet", "decode_packet", "raw_line", "uni_line", "cal_lines", "parse_cal_line", "echo_matches"]

G_PER_COUNT = 1.0 / 8192.0
"""Accelerometer, g per ``Raw:`` count (NXPMotionSense ``G_PER_COUNT``)."""
DEG_S_PER_COUNT = 1.0 / 16.0
"""Gyro, deg/s per ``Raw:`` count (NXPMotionSense ``DEG_PER_SEC_PER_COUNT``)."""
UT_PER_COUNT = 0.1
"""Magnetometer, uT per ``Raw:`` count (NXPMotionSense ``UT_PER_COUNT``)."""
PACKET_SIZE = 68
SIGNATURE = bytes((117, 84))
_INT16 = (-32768, 32767)
_SOFT_ORDER = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))  # offsets[10..15]
CAL1_DECIMALS, CAL2_DECIMALS = 3, 4


def crc16(data: bytes, crc: int = 0xFFFF) -> int:
    """CRC-16 with the reflected polynomial 0xA001, from ``crc`` (``Adafruit_Sensor_Calibration::crc16_update``
    over every byte).

    Examples
    --------
    >>> hex(crc16(b"123456789"))  # CRC-16/MODBUS's check value
    '0x4b37'
    """
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


@dataclass(frozen=True)
class CalPacket:
    """The sixteen numbers of a MotionCal calibration packet.

    Attributes
    ----------
    accel_zero_g : ndarray, shape (3,)
        Subtracted from the accelerometer, m/s^2 (Adafruit's unit).
    gyro_zero_rate : ndarray, shape (3,)
        Subtracted from the gyro, rad/s.
    hard_iron_ut : ndarray, shape (3,)
        Subtracted from the magnetometer first, uT.
    field_ut : float
        The field magnitude after calibration, uT.
    soft_iron : ndarray, shape (3, 3)
        Symmetric; multiplies the magnetometer after the hard iron: ``B = soft_iron @ (m - hard_iron_ut)``.
    """

    accel_zero_g: np.ndarray
    gyro_zero_rate: np.ndarray
    hard_iron_ut: np.ndarray
    field_ut: float
    soft_iron: np.ndarray

    def floats(self) -> np.ndarray:
        """The sixteen numbers in packet order, shape (16,)."""
        s = self.soft_iron
        return np.concatenate([self.accel_zero_g, self.gyro_zero_rate, self.hard_iron_ut, [self.field_ut],
                               [s[i, j] for i, j in _SOFT_ORDER]]).astype(float)

    def echoed(self) -> tuple[np.ndarray, np.ndarray]:
        """What a sketch holding this packet prints: ``Cal1:``'s ten and ``Cal2:``'s nine numbers, as float32."""
        f = self.floats().astype(np.float32).astype(float)
        return f[:10], _soft_from(f[10:]).ravel()


def encode_packet(packet: CalPacket) -> bytes:
    """The 68 bytes MotionCal sends (module docstring); ValueError for a number float32 cannot hold."""
    values = packet.floats()
    if not np.all(np.isfinite(values)) or np.any(np.abs(values) > np.finfo(np.float32).max):
        raise ValueError(f"the packet holds float32 numbers: got {values.tolist()}")
    body = SIGNATURE + struct.pack("<16f", *values)
    return body + struct.pack("<H", crc16(body))


def decode_packet(data: bytes) -> CalPacket:
    """Read a packet as the receiver does: ValueError unless it is 68 bytes, signed, and its CRC over all
    68 bytes is 0."""
    if len(data) != PACKET_SIZE:
        raise ValueError(f"a MotionCal packet is {PACKET_SIZE} bytes, got {len(data)}")
    if data[:2] != SIGNATURE:
        raise ValueError(f"a MotionCal packet starts with 117, 84, got {data[0]}, {data[1]}")
    if crc16(data) != 0:
        raise ValueError("the packet's CRC-16 does not match its contents")
    f = np.array(struct.unpack("<16f", data[2:66]), dtype=float)
    return CalPacket(f[0:3], f[3:6], f[6:9], float(f[9]), _soft_from(f[10:]))


def _soft_from(unique: np.ndarray) -> np.ndarray:
    s = np.empty((3, 3))
    for value, (i, j) in zip(unique, _SOFT_ORDER):
        s[i, j] = s[j, i] = value
    return s


def raw_line(accel_g, gyro_rad_s, mag_ut) -> bytes:
    """A ``Raw:`` line of counts as NXPMotionSense sends it (rounded to the nearest count, clipped to int16).

    Examples
    --------
    >>> raw_line([0, 0, 1], [0, 0, 0], [20, 0, -40])
    b'Raw:0,0,8192,0,0,0,200,0,-400\\r\\n'
    """
    counts = np.concatenate([np.asarray(accel_g, float) / G_PER_COUNT,
                             np.degrees(np.asarray(gyro_rad_s, float)) / DEG_S_PER_COUNT,
                             np.asarray(mag_ut, float) / UT_PER_COUNT])
    counts = np.clip(np.rint(counts), *_INT16).astype(int)
    return ("Raw:" + ",".join(str(c) for c in counts)).encode("ascii") + b"\r\n"


def uni_line(accel_g, gyro_rad_s, mag_ut) -> bytes:
    """A ``Uni:`` line as Adafruit's sketch prints it: m/s^2 and uT with 2 decimals, rad/s with 4."""
    a = np.asarray(accel_g, float) * STANDARD_GRAVITY
    cells = [f"{v:.2f}" for v in a] + [f"{v:.4f}" for v in gyro_rad_s] + [f"{v:.2f}" for v in mag_ut]
    return ("Uni:" + ",".join(cells)).encode("ascii") + b"\r\n"


def cal_lines(packet: CalPacket) -> bytes:
    """The ``Cal1:`` and ``Cal2:`` lines a sketch holding ``packet`` prints (3 and 4 decimals)."""
    cal1, cal2 = packet.echoed()
    return (("Cal1:" + ",".join(f"{v:.{CAL1_DECIMALS}f}" for v in cal1) + "\r\n"
             + "Cal2:" + ",".join(f"{v:.{CAL2_DECIMALS}f}" for v in cal2) + "\r\n").encode("ascii"))


def parse_cal_line(text: str) -> tuple[str, np.ndarray] | None:
    """``("Cal1", ten numbers)`` or ``("Cal2", nine)`` from an echo line (without its end), else None."""
    for tag, n in (("Cal1:", 10), ("Cal2:", 9)):
        if text.startswith(tag):
            try:
                values = np.array([float(c) for c in text[len(tag):].split(",")])
            except ValueError:
                return None
            if len(values) != n or not np.all(np.isfinite(values)):
                return None
            return tag[:-1], values
    return None


def echo_matches(packet: CalPacket, cal1, cal2) -> tuple[bool, str]:
    """Whether the echoed ``Cal1``/``Cal2`` numbers are the packet's, to the decimals the sketch prints.

    A number printed with ``d`` decimals is within half a unit of its last digit of the float32 the
    device holds (plus float32's own rounding); a difference beyond that is another calibration.

    Returns
    -------
    ok : bool
    words : str
        The largest difference and where, for the report.
    """
    want1, want2 = packet.echoed()
    worst, where = 0.0, ""
    for name, got, want, decimals in (("Cal1", cal1, want1, CAL1_DECIMALS), ("Cal2", cal2, want2, CAL2_DECIMALS)):
        tol = 0.5 * 10.0 ** -decimals + 1e-6 * np.abs(want)
        excess = np.abs(np.asarray(got, float) - want) / tol
        k = int(np.argmax(excess))
        if excess[k] > worst:
            worst, where = float(excess[k]), f"{name}[{k}] {got[k]:.{decimals}f} for {want[k]:.{decimals}f}"
    return worst <= 1.0, ("every number as sent" if worst <= 1.0 else f"differs: {where}")


def int16_counts(cells: list[str]) -> list[int] | None:
    """Nine ``Raw:`` cells as integers in int16 range (MotionCal's ``ascii_parse`` rule), else None."""
    try:
        counts = [int(c) for c in cells]
    except ValueError:
        return None
    lo, hi = _INT16
    return counts if all(lo <= c <= hi for c in counts) else None


def is_finite(values) -> bool:
    return all(map(math.isfinite, values))
