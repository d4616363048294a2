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
  any ``Adafruit_Sensor_Calibration`` (EEPROM or SDFat); ``cal.saveCalibration()`` then stores them.
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

from ..calibration import Calibration
from ._common import (
    c_float,
    check_float32,
    describe,
    factor,
    float32_text,
    physical_unit,
    plain,
    rotated_frame_warning,
)

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
    lines = [f"    cal.mag_hardiron[{i}] = {c_float(v)};" for i, v in enumerate(hard)]
    lines += [f"    cal.mag_softiron[{i}] = {c_float(v)};" for i, v in enumerate(soft)]
    lines.append(f"    cal.mag_field = {c_float(values['mag_field'])};  /* uT */")  # type: ignore[arg-type]
    body = "\n".join(lines)
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
 * Use: magfit_set_calibration(cal); then cal.saveCalibration(); (EEPROM or SD/flash JSON).
 */
#ifndef {GUARD}
#define {GUARD}

#include <Adafruit_Sensor_Calibration.h>

static inline void magfit_set_calibration(Adafruit_Sensor_Calibration &cal)
{{
{body}
}}

#endif /* {GUARD} */
"""


def write_adafruit_json(calibration: Calibration, unit: str | None = None) -> str:
    """The JSON file Adafruit_Sensor_Calibration_SDFat loads (see the module docstring)."""
    values = adafruit_values(calibration, unit, "adafruit-json")
    return json.dumps(values, indent=2) + "\n"
