"""The motors' field in the firmware exports (docs/exports.md, "The motors' field").

magfit holds the term before the matrix, in the raw samples' axes (``corrected = M (raw − V − k c)``,
:mod:`magfit.motorterm`). Each firmware's own formula, from its source:

- **ArduPilot** ``AP_Compass_Backend::correct_field`` (libraries/AP_Compass/AP_Compass_Backend.cpp):
  ``mag += OFS; mag *= SCALE; mag = DIA/ODI · mag; mag += MOT · x`` with ``x`` the throttle 0-1
  (``COMPASS_MOTCT`` 1, ``Compass::_thr``) or the primary battery's current in amperes (``COMPASS_MOTCT`` 2,
  ``AP_BattMonitor::current_amps``): MOT is added **after** the matrix, in the body frame, in mG per A
  (``@Units: mGauss/A`` of COMPASS_MOT_X in AP_Compass.cpp) or mG at full throttle. With ArduPilot's
  corrected field ``D·SCALE·(R·x_mG + OFS) = k·SCALE·M (raw − V)`` (export/ardupilot.py; R the orientation,
  the identity for a sensor-frame calibration), the term ``−k·SCALE·M·k_m c`` after the matrix is::

      MOT = −k · SCALE · (D R) · k_m          # D R = M: the matrix that multiplies the raw field

- **PX4** ``calibration::Magnetometer::Correct`` (src/lib/sensor_calibration/Magnetometer.hpp):
  ``R · (S · ((raw + power · COMP) − OFF))`` with ``power`` the thrust (``CAL_MAG_COMP_TYP`` 1) or
  ``battery_status.current_a · 0.001`` (kA, types 2 and 3: battery instance 0 or 1;
  ``VehicleMagnetometer::UpdatePowerCompensation``), COMP in gauss per kA or gauss per unit thrust, added
  **before** the offset in the sensor frame::

      COMP = −k · k_m · 1000   (current: G/kA)        COMP = −k · k_m   (thrust: G)

``COMPASS_MOTCT`` and ``CAL_MAG_COMP_TYP`` are one setting for all compasses: when two compasses hold terms
of different regressors, the file takes the current (a measured quantity, the better regressor in PX4's own
guide) and writes zero terms, with the heading error that costs, for the others.

A format with no place for the term refuses a calibration that holds one, with the heading error that
leaving it out would cost at full current (:func:`omission_deg`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from ..calibration import Calibration
from ..errors import ExportError
from ..remedy import option
from ._common import float32_text
from ._heading import ASSUMPTION, heading_error_deg

__all__ = ["ARDUPILOT_MOTCT", "PX4_COMP_TYP", "chosen_regressor", "omission_deg", "refuse_motor"]

#: COMPASS_MOTCT values (AP_Compass.cpp: 0 Disabled, 1 Use Throttle, 2 Use Current).
ARDUPILOT_MOTCT = {"throttle": 1, "current": 2}
#: CAL_MAG_COMP_TYP values (PX4 MagCompensationType: 1 Throttle, 2 Current_inst0).
PX4_COMP_TYP = {"throttle": 1, "current": 2}
#: The documented @Range of COMPASS_MOT_* (AP_Compass.cpp).
MOT_RANGE_MG = 1000.0


def omission_deg(calibration: Calibration) -> float:
    """The worst heading error (degrees, :mod:`._heading`'s assumptions) of leaving the motor term out, at the
    largest regressor the recording held (full current or full throttle)."""
    if calibration.motor is None:
        return 0.0
    plain = replace(calibration, motor=None)
    shifted = replace(plain, offset=calibration.offset + calibration.motor.field(calibration.motor.full_scale))
    return heading_error_deg(shifted, plain.matrix, plain.offset)


def refuse_motor(calibration: Calibration, format: str) -> None:
    """Refuse a calibration with a motor term in a format that cannot hold one."""
    if calibration.motor is None:
        return
    term = calibration.motor
    at = f"{term.full_scale:.3g} A" if term.regressor == "current" else "full throttle"
    raise ExportError(
        f"the {format} format has no place for the motors' field ({term.regressor}): leaving it out costs a heading "
        f"error of up to {omission_deg(calibration):.1f} deg at {at} ({ASSUMPTION}); export to ardupilot, px4, c or "
        f"json, or calibrate with {option('motor', 'none')} to fit without the term",
        codes=("motor_not_exportable",),
        remedy=(("motor", "none"),),
    )


def chosen_regressor(calibrations: Sequence[Calibration]) -> str | None:
    """The one regressor a firmware setting can name for all compasses: the current when any holds one."""
    kinds = {c.motor.regressor for c in calibrations if c.motor is not None}
    if not kinds:
        return None
    return "current" if "current" in kinds else "throttle"


def ardupilot_mot(calibration: Calibration, linear: NDArray[np.float64], k: float, scale: float) -> NDArray[np.float64]:
    """COMPASS_MOT (mG per A, or mG at full throttle) for ArduPilot's ``D·SCALE·(R x + OFS)``, ``linear`` = D R."""
    assert calibration.motor is not None
    return np.asarray(-k * scale * (linear @ calibration.motor.coefficients), dtype=np.float64)


def px4_comp(calibration: Calibration, k: float) -> NDArray[np.float64]:
    """CAL_MAGn_xCOMP (G/kA for the current, G per unit thrust) for PX4's ``raw + power·COMP − OFF``."""
    assert calibration.motor is not None
    per = 1000.0 if calibration.motor.regressor == "current" else 1.0
    return np.asarray(-k * per * calibration.motor.coefficients, dtype=np.float64)


def mismatch_comment(calibration: Calibration, chosen: str, setting: str) -> list[str]:
    """The WARNING a compass whose term's regressor is not the one the file's single setting names gets."""
    assert calibration.motor is not None
    return [
        f"# WARNING: this compass's motors' field follows the {calibration.motor.regressor}, but {setting} is one "
        f"setting for all compasses and this file sets it to the {chosen}: its term is written as zero,",
        f"#   a heading error of up to {omission_deg(calibration):.1f} deg at full scale ({ASSUMPTION})",
    ]


def describe_term(calibration: Calibration) -> str:
    """One comment line: the term as magfit holds it."""
    assert calibration.motor is not None
    term = calibration.motor
    per = "A" if term.regressor == "current" else "full throttle"
    values = ", ".join(float32_text(v) for v in term.coefficients)
    return (
        f"# motors' field (magfit): k = ({values}) {calibration.unit or 'units'} per {per}, raw axes, lag "
        f"{1000 * term.lag_s:.0f} ms; up to {omission_deg(calibration):.1f} deg of heading at full scale"
    )
