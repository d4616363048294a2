"""Adafruit_Sensor_Calibration (MotionCal's Arduino side): ``mag_hardiron``, ``mag_softiron``, ``mag_field`` in µT.

``Adafruit_Sensor_Calibration::calibrate`` (Adafruit_Sensor_Calibration.cpp, adafruit/
Adafruit_Sensor_Calibration 80dfeba) corrects a ``sensors_event_t`` magnetic event, in µT (the unit
of Adafruit's unified sensor events)::

    m = event.magnetic - mag_hardiron                   # hard iron SUBTRACTED
    event.magnetic[i] = sum over j of mag_softiron[3*i + j] * m[j]   # row-major 3x3

so ``mag_hardiron = k * offset`` and ``mag_softiron = matrix`` flattened row by row, with ``k`` the
factor from the samples' unit to µT; ``mag_field = k * field_strength`` (the library's "magnetic field
magnitude in uTesla"). Two forms:

- ``adafruit`` (.h): a C++ header with ``magfit_set_calibration(cal)``, which fills the three members of
  any ``Adafruit_Sensor_Calibration``; ``cal.saveCalibration()`` then stores them. The backends differ
  (Adafruit_Sensor_Calibration_SDFat.cpp, Adafruit_Sensor_Calibration_EEPROM.cpp): SDFat (a JSON file on
  SD or flash) keeps all nine soft-iron values; EEPROM, the backend on AVR, ESP8266, ESP32 and Teensy
  (``ADAFRUIT_SENSOR_CALIBRATION_USE_EEPROM``), saves ``mag_softiron[0, 4, 8, 1, 2, 5]`` and reloads a
  symmetric matrix. For a matrix that is not symmetric (a Cholesky root, a vehicle-frame calibration) the
  header adds an overload for ``Adafruit_Sensor_Calibration_EEPROM`` (C++ picks it for that class) which
  writes the symmetric root ``sqrtm(Mᵀ M)`` (:func:`eeprom_matrix`: exact for ``|corrected|``, the rotation
  and its heading cost stated) for a Cholesky root (whose rotation is an artefact) and for any other
  matrix when that cost is within :data:`._common.ROTATION_TOLERANCE_DEG`, and is deleted (a call does
  not compile, the comment says why) when it is larger.
- ``adafruit-json`` (.json): the file ``Adafruit_Sensor_Calibration_SDFat::loadCalibration`` reads
  (``sensor_calib.json`` by default) with exactly the keys it looks up, ``mag_hardiron`` [3],
  ``mag_softiron`` [9] and ``mag_field``. Keys it does not read are left out: the library parses into
  a ``StaticJsonDocument<512>``, with little room to spare. ``gyro_zerorate`` and ``accel_zerog``
  are absent, so they load as 0: merge your own into the file if you have them.

Refused: no physical unit (the library works in µT), and values outside float32's range. A
non-symmetric matrix (``root="cholesky"``) is written as fitted, with the warning of
:func:`._common.rotated_frame_warning` in the header's comment (JSON has no comments: see the header).
"""

from __future__ import annotations

import json
import textwrap

import numpy as np
from numpy.typing import NDArray

from ..calibration import Calibration
from ..rotations import polar_decomposition
from ._common import (
    ROTATION_TOLERANCE_DEG,
    SYMMETRY_TOLERANCE,
    c_float,
    check_float32,
    describe,
    factor,
    float32_text,
    physical_unit,
    plain,
    rotated_frame_warning,
)
from ._heading import ASSUMPTION, heading_error_deg

GUARD = "MAGFIT_ADAFRUIT_CALIBRATION_H"


def adafruit_values(calibration: Calibration, unit: str | None, target: str) -> dict[str, list[float] | float]:
    """``mag_hardiron``, ``mag_softiron`` (row-major) and ``mag_field``, in µT.

    Raises
    ------
    ExportError
        No physical unit, or a value outside float32's range.
    OptionError
        ``unit`` is not a unit magfit knows.
    """
    k = factor(physical_unit(calibration, unit, target, "uT"), "uT")
    values: dict[str, list[float] | float] = {
        "mag_hardiron": [float(v) for v in k * calibration.offset],
        "mag_softiron": [float(v) for v in calibration.matrix.ravel()],  # row-major, as calibrate() reads it
        "mag_field": float(k * calibration.field_strength),
    }
    check_float32(values, target)  # type: ignore[arg-type]
    return values


def eeprom_matrix(calibration: Calibration) -> tuple[NDArray[np.float64], float, str] | None:
    """What the EEPROM backend can keep of a non-symmetric matrix: (S, heading cost in degrees, why); None if symmetric.

    ``Adafruit_Sensor_Calibration_EEPROM::saveCalibration`` stores ``mag_softiron[0, 4, 8, 1, 2, 5]`` and
    ``loadCalibration`` rebuilds ``[3] = [1]``, ``[6] = [2]``, ``[7] = [5]``: a symmetric matrix. A matrix M
    that is not symmetric would come back as another matrix (its upper triangle mirrored), wrong by up to
    180 degrees of heading. The symmetric matrix with the same ``Mᵀ M`` (paper eq. 2: the same ellipsoid, the
    same ``|corrected|``) is the symmetric root ``S = sqrtm(Mᵀ M)`` (M = Q S, :func:`magfit.rotations.
    polar_decomposition`); what it loses is the rotation Q, whose heading cost is computed here
    (:func:`._heading.heading_error_deg`). For a Cholesky root Q is an artefact of the factorisation, for a
    vehicle-frame calibration it is the magnetometer's mounting.
    """
    m = calibration.matrix
    if float(np.max(np.abs(m - m.T))) <= SYMMETRY_TOLERANCE * float(np.max(np.abs(m))):
        return None
    rotation, root = polar_decomposition(m)
    if np.linalg.det(rotation) < 0:
        return root, 180.0, "a mirror (left-handed axes), which no symmetric positive matrix holds"
    cost = heading_error_deg(calibration, root, calibration.offset)
    if calibration.frame == "vehicle":
        why = "the magnetometer's alignment with the vehicle (the rotation of the vehicle-frame matrix)"
    elif calibration.details.get("root") == "cholesky":
        why = "the rotation of the Cholesky root, which the samples do not determine"
    else:
        why = "the rotation of the non-symmetric matrix"
    return root, cost, why


def write_adafruit(calibration: Calibration, unit: str | None = None) -> str:
    """A C++ header that fills an ``Adafruit_Sensor_Calibration`` object (see the module docstring)."""
    values = adafruit_values(calibration, unit, "adafruit")
    source = physical_unit(calibration, unit, "adafruit", "uT")
    k = factor(source, "uT")
    hard = values["mag_hardiron"]
    soft = values["mag_softiron"]
    assert isinstance(hard, list) and isinstance(soft, list)
    facts = "\n".join(f" * {line}" for line in describe(calibration, source.name))
    warning = rotated_frame_warning(calibration)
    if warning:
        facts += f"\n * {plain(warning)}"
    field = f"    cal.mag_field = {c_float(values['mag_field'])};  /* uT */"  # type: ignore[arg-type]
    lines = [f"    cal.mag_hardiron[{i}] = {c_float(v)};" for i, v in enumerate(hard)]
    lines += [f"    cal.mag_softiron[{i}] = {c_float(v)};" for i, v in enumerate(soft)]
    lines.append(field)
    body = "\n".join(lines)
    eeprom = _eeprom_section(calibration, hard, field)
    return f"""/* Adafruit_Sensor_Calibration (MotionCal's Arduino library): magnetometer calibration in uT.
 * Generated file: re-export instead of editing.
 *
 * Adafruit_Sensor_Calibration::calibrate(event) applies, to event.magnetic in uT:
 *     m = magnetic - mag_hardiron
 *     magnetic[i] = mag_softiron[3*i + 0] * m[0] + mag_softiron[3*i + 1] * m[1] + mag_softiron[3*i + 2] * m[2]
 * = magfit's corrected = matrix * (raw - offset): mag_hardiron = offset * {float32_text(k)} ({source.name} -> uT),
 *   mag_softiron = matrix row by row, mag_field = field strength in uT.
{facts}
 *
 * Use: magfit_set_calibration(cal); then cal.saveCalibration(); to keep it. What the backends keep:
 *   Adafruit_Sensor_Calibration_SDFat (a JSON file on SD or flash): all nine mag_softiron values.
 *   Adafruit_Sensor_Calibration_EEPROM (the backend on AVR, ESP8266, ESP32, Teensy): six of them,
 *     mag_softiron[0, 4, 8, 1, 2, 5]; loadCalibration() rebuilds [3] = [1], [6] = [2], [7] = [5],
 *     a symmetric matrix (Adafruit_Sensor_Calibration_EEPROM.cpp).
 */
#ifndef {GUARD}
#define {GUARD}

#include <Adafruit_Sensor_Calibration.h>

/* The calibration as fitted: what calibrate() applies, and what the SD/flash backend saves and reloads. */
static inline void magfit_set_calibration(Adafruit_Sensor_Calibration &cal)
{{
{body}
}}
{eeprom}
#endif /* {GUARD} */
"""


def _eeprom_section(calibration: Calibration, hard: list[float], field: str) -> str:
    """The EEPROM backend's overload of ``magfit_set_calibration``: a matrix that survives its save and load."""
    kept = eeprom_matrix(calibration)
    if kept is None:
        return "\n/* The matrix is symmetric: the EEPROM backend saves and reloads it whole. */\n"
    root, cost, why = kept
    cholesky = calibration.frame == "sensor" and calibration.details.get("root") == "cholesky" and cost < 180.0
    if cost > ROTATION_TOLERANCE_DEG and not cholesky:
        text = (
            f"The EEPROM backend saves a symmetric matrix only, and this one is not: it holds {why}. Reloaded "
            f"from EEPROM it would be another matrix; its symmetric equivalent sqrtm(M^T M) keeps |corrected| "
            f"but drops that rotation, a heading error of up to {cost:.1f} deg ({ASSUMPTION}). So there is no "
            "magfit_set_calibration for Adafruit_Sensor_Calibration_EEPROM (a call does not compile): use the "
            "SD/flash backend, or apply the calibration without saving it "
            "(magfit_set_calibration(static_cast<Adafruit_Sensor_Calibration &>(cal)) at every start)."
        )
        comment = "\n".join(f" * {line}" for line in textwrap.wrap(text, 100, break_on_hyphens=False))
        return f"""
#if defined(ADAFRUIT_SENSOR_CALIBRATION_USE_EEPROM)
/*
{comment}
 */
static inline void magfit_set_calibration(Adafruit_Sensor_Calibration_EEPROM &cal) = delete;
#endif
"""
    text = (
        f"The EEPROM backend saves a symmetric matrix only, and this one is not: it holds {why}. For "
        "Adafruit_Sensor_Calibration_EEPROM this overload writes the symmetric root sqrtm(M^T M) instead: the "
        "same ellipsoid, the same |corrected|, and what saveCalibration() stores is what loadCalibration() "
        f"gives back; it drops the rotation, a heading difference of up to {cost:.2f} deg from magfit's "
        f"correction ({ASSUMPTION})"
        + (
            ", which is the Cholesky factor's artefact: the symmetric root is the one that adds no rotation."
            if cholesky
            else "."
        )
    )
    comment = "\n".join(f" * {line}" for line in textwrap.wrap(text, 100, break_on_hyphens=False))
    check_float32({"mag_softiron": root}, "adafruit")
    lines = [f"    cal.mag_hardiron[{i}] = {c_float(v)};" for i, v in enumerate(hard)]
    lines += [f"    cal.mag_softiron[{i}] = {c_float(v)};" for i, v in enumerate(root.ravel())]
    lines.append(field)
    body = "\n".join(lines)
    return f"""
#if defined(ADAFRUIT_SENSOR_CALIBRATION_USE_EEPROM)
/*
{comment}
 */
static inline void magfit_set_calibration(Adafruit_Sensor_Calibration_EEPROM &cal)
{{
{body}
}}
#endif
"""


def write_adafruit_json(calibration: Calibration, unit: str | None = None) -> str:
    """The JSON file Adafruit_Sensor_Calibration_SDFat loads (see the module docstring)."""
    values = adafruit_values(calibration, unit, "adafruit-json")
    return json.dumps(values, indent=2) + "\n"
