"""MotionCal's 68-byte calibration packet, which Adafruit's calibration sketches receive and store.

Layout (MotionCal ``rawdata.c``, ``send_calibration``; read back by the ``receiveCalibration`` function of
the sketches built on Adafruit_Sensor_Calibration, which stores the same layout in EEPROM,
``Adafruit_Sensor_Calibration_EEPROM.cpp``):

====== ======= ================================================================================
bytes  type    content
====== ======= ================================================================================
0-1    u8 u8   signature 117, 84 (``0x75 0x54``)
2-13   3 f32   accelerometer zero-g offsets (MotionCal sends 0)
14-25  3 f32   gyroscope zero-rate offsets (MotionCal sends 0)
26-37  3 f32   magnetometer hard-iron offset, µT
38-41  f32     field strength, µT
42-65  6 f32   soft-iron matrix, symmetric: [0][0], [1][1], [2][2], [0][1], [0][2], [1][2]
66-67  u16     CRC-16 of bytes 0-65: reflected polynomial 0xA001, initial value 0xFFFF, no final xor
               (CRC-16/MODBUS), least significant byte first
====== ======= ================================================================================

Every float is IEEE-754 single precision, least significant byte first. The receiver runs the same CRC
over all 68 bytes and accepts the packet when the result is 0 (the residue of a CRC appended LSB first).

The firmware applies ``corrected = softiron @ (raw_uT - hardiron)`` (``Adafruit_Sensor_Calibration::
calibrate``; MotionCal's ``apply_calibration``): magfit's own convention, with the soft-iron matrix the
*correcting* matrix. Only its upper triangle travels, so the matrix must be symmetric, which magfit's
default (symmetric square root) is.
"""

from __future__ import annotations

import struct

import numpy as np

from ..calibration import Calibration
from ..errors import ExportError, OptionError
from ..units import conversion_factor

__all__ = ["PACKET_SIZE", "SIGNATURE", "crc16", "motioncal_packet"]

PACKET_SIZE = 68
SIGNATURE = bytes((117, 84))
#: Largest asymmetry (relative to the largest entry) a matrix may have and still travel as its upper triangle.
_SYMMETRY_TOLERANCE = 1e-6


def crc16(data: bytes, crc: int = 0xFFFF) -> int:
    """CRC-16 with the reflected polynomial 0xA001, as MotionCal's ``crc16`` and Adafruit's ``crc16_update``."""
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


def motioncal_packet(calibration: Calibration, *, unit: str | None = None) -> bytes:
    """The 68 bytes that carry ``calibration`` to a board running an Adafruit/MotionCal calibration sketch.

    Parameters
    ----------
    calibration : Calibration
        ``corrected = matrix @ (raw - offset)``; its matrix must be symmetric.
    unit : str, optional
        Unit of the samples it was fitted on, overriding ``calibration.unit``; the packet carries µT, so
        it must be a physical unit (``uT``, ``nT``, ``mG``, ``G`` ...).

    Raises
    ------
    ExportError
        No physical unit, a matrix that is not symmetric, or values a 32-bit float cannot carry.
    """
    source = unit if unit is not None else calibration.unit
    if source is None:
        raise ExportError(
            "the MotionCal packet carries microtesla, but the samples' unit is unknown; give it with --unit"
        )
    try:
        to_ut = conversion_factor(source, "uT")
    except OptionError as error:  # an unknown unit, or raw counts
        raise ExportError(f"the MotionCal packet carries microtesla: {error}") from None
    matrix = np.asarray(calibration.matrix, dtype=np.float64)
    if np.max(np.abs(matrix - matrix.T)) > _SYMMETRY_TOLERANCE * np.max(np.abs(matrix)):
        raise ExportError(
            "the MotionCal packet carries a symmetric soft-iron matrix (its upper triangle); this calibration's "
            "matrix is not symmetric: refit with the default root='symmetric'"
        )
    offset = np.asarray(calibration.offset, dtype=np.float64) * to_ut
    values = [
        0.0, 0.0, 0.0,  # accelerometer zero-g: magfit does not calibrate it (MotionCal sends 0 too)
        0.0, 0.0, 0.0,  # gyroscope zero-rate
        *offset,
        calibration.field_strength * to_ut,
        matrix[0, 0], matrix[1, 1], matrix[2, 2], matrix[0, 1], matrix[0, 2], matrix[1, 2],
    ]  # fmt: skip
    if not all(np.isfinite(np.float32(v)) for v in values):
        raise ExportError("a value of the calibration does not fit in a 32-bit float; the packet cannot carry it")
    body = SIGNATURE + struct.pack("<16f", *values)
    return body + struct.pack("<H", crc16(body))
