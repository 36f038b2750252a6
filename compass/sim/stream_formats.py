"""What a simulated module sends in the stream formats of real boards, and how it takes a calibration.

- ``motioncal``: Adafruit's ``calibration.ino`` (``Adafruit_AHRS/examples/calibration``): a ``Raw:``
  line then a ``Uni:`` line per sample, ``Cal1:``/``Cal2:`` echoes of the stored calibration every
  :data:`ECHO_EVERY` samples, and the 68-byte packet received as its ``receiveCalibration()`` does;
- ``motioncal-raw``: PJRC's ``CalibrateSensors.ino``: ``Raw:`` lines only, the same echoes and receiver;
- ``csv``: bare numbers, :data:`CSV_COLUMNS`, space separated, no header (``compass live --columns ...``).

The field of a MotionCal board is in uT (:func:`outputs_per_ut` must be 1): :func:`board_model`
is such a board's magnetometer.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from ..io import motioncal as mc
from ..model import SensorModel
from ..response import LinearResponse

__all__ = ["DEVICE_FORMATS", "CSV_COLUMNS", "ECHO_EVERY", "board_model", "outputs_per_ut", "sample_lines",
           "PacketReceiver"]

DEVICE_FORMATS = ("compass", "motioncal", "motioncal-raw", "csv")
CSV_COLUMNS = ("t_s", "ax", "ay", "az", "gx", "gy", "gz", "mx", "my", "mz")
ECHO_EVERY = 50
"""Samples between two ``Cal1:``/``Cal2:`` echoes (Adafruit's sketch: at its loop count 50 and every 100)."""


def board_model() -> SensorModel:
    """A 9-axis board's magnetometer in uT: hard iron (18, -11, 32) uT, gains 0.96-1.04 per uT, axes a few
    tenths of a degree off, |B| 50 uT, dip 60 degrees, noise 0.15 uT (counts of 0.1 uT quantise it)."""
    directions = Rotation.from_rotvec([0.004, -0.006, 0.003]).apply(np.eye(3))
    responses = tuple(LinearResponse(o, k, (-100.0, 100.0)) for o, k in zip((18.0, -11.0, 32.0), (0.96, 1.04, 1.01)))
    return SensorModel(("mx", "my", "mz"), directions, responses, 50.0, 50.0, 60.0, noise=np.full(3, 0.15))


def outputs_per_ut(model: SensorModel) -> float:
    """Output units per uT of the model's channels (median gain): 1 for a magnetometer that reads uT, NaN
    when the calibration does not say what its unit is (no ``field_ut`` and a |B| outside 25-65)."""
    magnitude = model.field_norm
    per_field_unit = float(np.median(model.gains))
    if model.field_ut is not None:
        return per_field_unit * magnitude / model.field_ut
    return per_field_unit if 25.0 <= magnitude <= 65.0 else float("nan")


def sample_lines(fmt: str, t_s, raw, accel_g, gyro_rad_s) -> list[bytes]:
    """One sample's bytes per row in ``fmt`` (not ``compass``: see :class:`compass.sim.device.PtyDevice`).

    Parameters
    ----------
    t_s : ndarray, shape (n,)
    raw : ndarray, shape (n, 3)
        The field channels (uT for the MotionCal formats).
    accel_g, gyro_rad_s : ndarray, shape (n, 3)
    """
    if fmt == "csv":
        return [(f"{t:.4f} " + " ".join(f"{v:.6f}" for v in (*a, *g)) + " " + " ".join(f"{v:.7g}" for v in m)
                 ).encode("ascii") + b"\r\n" for t, a, g, m in zip(t_s, accel_g, gyro_rad_s, raw)]
    if fmt == "motioncal-raw":
        return [mc.raw_line(a, g, m) for a, g, m in zip(accel_g, gyro_rad_s, raw)]
    if fmt == "motioncal":
        return [mc.raw_line(a, g, m) + mc.uni_line(a, g, m) for a, g, m in zip(accel_g, gyro_rad_s, raw)]
    raise ValueError(f"no sample lines for format {fmt!r}; expected one of {', '.join(DEVICE_FORMATS[1:])}")


class PacketReceiver:
    """The sketches' ``receiveCalibration()``: bytes in, a stored :class:`compass.io.motioncal.CalPacket` out.

    Byte by byte: the first must be 117 and the second 84 (else start again); at 68 bytes the CRC over
    all of them must be 0; if it is not, the search restarts at a later ``117, 84`` inside the
    buffer, or a final 117.

    Attributes
    ----------
    stored : CalPacket
        What the board holds (Adafruit's defaults until a packet arrives: zeros, identity, 50 uT).
    received, rejected : int
        Packets accepted, 68-byte buffers whose CRC failed.
    """

    def __init__(self):
        self.stored = mc.CalPacket(np.zeros(3), np.zeros(3), np.zeros(3), 50.0, np.eye(3))
        self.received = 0
        self.rejected = 0
        self._buf = bytearray()

    def feed(self, data: bytes) -> bool:
        """Take bytes from the host; True when a packet was accepted (and stored)."""
        accepted = False
        for b in data:
            if not self._buf and b != 117:
                continue
            if len(self._buf) == 1 and b != 84:
                self._buf.clear()
                continue
            self._buf.append(b)
            if len(self._buf) < mc.PACKET_SIZE:
                continue
            try:
                self.stored = mc.decode_packet(bytes(self._buf))
            except ValueError:
                self.rejected += 1
                start = next((i for i in range(2, mc.PACKET_SIZE - 1)
                              if self._buf[i] == 117 and self._buf[i + 1] == 84), None)
                if start is not None:
                    del self._buf[:start]
                else:
                    self._buf = bytearray([117]) if self._buf[-1] == 117 else bytearray()
                continue
            self.received += 1
            accepted = True
            self._buf.clear()
        return accepted
