"""PX4's magnetometer temperature compensation ``TC_Mn_*`` from the offset's drift a log determines.

PX4's convention, from its source (PX4-Autopilot, src/modules/temperature_compensation):

- ``TemperatureCompensation::update_offsets_mag`` calls ``calc_thermal_offsets_3D`` (TemperatureCompensation.cpp):
  the temperature is clipped to ``[TMIN, TMAX]``, ``dT = T − TREF``, and per axis i::

      thermal_offset_i = X0_i + X1_i dT + X2_i dT² + X3_i dT³                                        (P1)

  with ``TC_Mn_X{0..3}_{0,1,2}``, applied to the sensor whose device id is ``TC_Mn_ID`` (``set_sensor_id_mag``),
  when ``TC_M_ENABLE`` is 1 (``parameters_update``); published in ``sensor_correction.mag_offset_n``.
- ``calibration::Magnetometer::SensorCorrectionsUpdate`` (Magnetometer.cpp, PX4's sensor calibration library)
  copies ``sensor_correction.mag_offset_n`` of the sensor whose device id matches into the magnetometer's
  ``_thermal_offset``, in the ``sensor_mag`` frame and unit (gauss). PX4 subtracts a thermal offset from the raw
  reading beside the calibration's offset in every other sensor's ``Correct`` (the accelerometer's
  and the gyroscope's ``R · (data − _thermal_offset − _offset)``, the barometer's ``data − _thermal_offset −
  _offset``); for the magnetometer that would read::

      corrected = R · (S · ((raw + power · COMP) − thermal_offset(T) − OFF))                         (P2)

  **What the source shows: computed, published, not subtracted.** In every version of PX4's source that magfit
  could read (the index holds 33 versions of src/lib/sensor_calibration/Magnetometer.hpp and 51 of
  Magnetometer.cpp, the newest with ``sensor::configuration``), ``calibration::Magnetometer::Correct``
  (Magnetometer.hpp) is ``R · (S · ((raw + power · COMP) − OFF))``: ``SensorCorrectionsUpdate`` (Magnetometer.cpp)
  stores ``sensor_correction.mag_offset_n`` in ``_thermal_offset`` and nothing subtracts it;
  ``VehicleMagnetometer::Run`` (src/modules/sensors/vehicle_magnetometer/VehicleMagnetometer.cpp) publishes
  ``Correct`` of each ``sensor_mag`` report; no magnetometer code calls ``thermal_offset()`` (the accelerometer's
  and the gyroscope's calibration routines do). PX4's documentation says releases up to 1.14 do not compensate
  the magnetometer for temperature; pull request 22701 (2024) made the module publish the magnetometer's offsets.
- PX4's own onboard calibration (``TemperatureCalibrationMag``, temperature_calibration/mag.cpp) fits the raw
  ``sensor_mag`` x, y, z against ``sensor_mag.temperature − TREF``, sets ``X0 = 0`` ("normalise the correction to
  be zero at the reference temperature") and writes ``TC_Mn_X{3-j}_{axis}``, ``TC_Mn_TMAX/TMIN/TREF`` and
  ``TC_Mn_ID``: ``CAL_MAGn_OFF`` is the offset at ``TREF``.

magfit's drift (:mod:`magfit.temperature`, eq. T1) is the offset's change per °C, ``V(T) = V + d (T − T̄)``,
with ``V`` the whole log's offset, in the sensor's axes. So, with ``k`` the factor to gauss::

    TREF = T̄,  X0 = 0,  X1 = k d,  X2 = X3 = 0,  TMIN/TMAX = the log's range,  OFF = k V            (P3)

A flight spans a few degrees: a straight line is all it determines, so the cubic's higher coefficients are
written as zero (and said); PX4 clips the temperature to ``[TMIN, TMAX]``, so the line is never extrapolated
beyond what the log saw. An axis whose drift is within two of its one-sigmas of zero is written as zero. An
undetermined drift is refused (code ``undetermined``) with its reason.

Because (P2) is not what the source read applies, the file says so, with what is at stake: ``OFF`` is the offset
at ``TREF``, so a firmware that ignores ``TC_Mn_*`` is right at ``TREF`` and off by ``X1 (T − TREF)`` elsewhere, at most
:func:`unapplied_offset` (the largest over ``[TMIN, TMAX]``): the block costs nothing where it is not applied,
and corrects the drift where it is applied as (P2).
"""

from __future__ import annotations

import numpy as np

from ..errors import ExportError, OptionError
from ..temperature import TemperatureDrift
from ..units import get_unit
from ._common import SlotParameters, factor, float32_text

__all__ = ["SIGNIFICANCE", "px4_temperature", "unapplied_offset"]

#: A drift within this many one-sigmas of zero is written as zero.
SIGNIFICANCE = 2.0


def unapplied_offset(drift: TemperatureDrift, slope: np.ndarray) -> float:
    """The largest offset error over ``[TMIN, TMAX]`` = the log's range of a firmware that ignores ``TC_Mn_*``
    while ``OFF`` is the offset at ``TREF``: ``max |slope (T − TREF)|``, in ``slope``'s unit."""
    low, high = drift.range_c
    return float(np.linalg.norm(slope) * max(abs(low - drift.reference_c), abs(high - drift.reference_c)))


def px4_temperature(drift: TemperatureDrift, *, slot: int, device_id: int | None) -> SlotParameters:
    """The ``TC_M_ENABLE`` and ``TC_Mn_*`` parameters (slot ``n`` = ``slot``) of eq. (P3), with their comments.

    Raises
    ------
    ExportError
        The drift is not determined (code ``undetermined``, the drift's own reason).
    OptionError
        No device id: PX4 applies ``TC_Mn_*`` only to the sensor whose id is ``TC_Mn_ID``.
    """
    prefix = f"TC_M{slot}_"
    if not drift.determined:
        reason = drift.reasons[0] if drift.reasons else "the log does not determine it"
        raise ExportError(
            f"PX4's temperature compensation ({prefix}*) is not written: the offset's drift with temperature is "
            f"not determined: {reason}",
            codes=("undetermined",),
        )
    if device_id is None:
        raise OptionError(
            f"PX4 applies {prefix}* only to the magnetometer whose device id is {prefix}ID, and this calibration's "
            "device id is not known: give device_id=... (the sensor_mag device_id)"
        )
    k = factor(get_unit(drift.unit), "G")
    significant = np.abs(drift.drift) > SIGNIFICANCE * drift.sigma
    slope = np.where(significant, k * drift.drift, 0.0)
    low, high = drift.range_c
    parameters: dict[str, float] = {"TC_M_ENABLE": 1.0, f"{prefix}ID": float(device_id)}
    for power in (3, 2, 1, 0):
        for axis in range(3):
            parameters[f"{prefix}X{power}_{axis}"] = float(slope[axis]) if power == 1 else 0.0
    parameters |= {f"{prefix}TREF": drift.reference_c, f"{prefix}TMIN": low, f"{prefix}TMAX": high}
    values = ", ".join(float32_text(v) for v in slope)
    at_stake = unapplied_offset(drift, slope)
    comments = [
        f"# temperature compensation ({prefix}*), to be subtracted with OFF from the raw reading (eq. P2),",
        "#   thermal_offset_i = X0_i + X1_i dT + X2_i dT^2 + X3_i dT^3, dT = clip(T, TMIN, TMAX) - TREF, in gauss",
        "#   (TemperatureCompensation::calc_thermal_offsets_3D; only while TC_M_ENABLE = 1, for the sensor TC_Mn_ID)",
        f"# fitted: X1 = ({values}) G/degC (x, y, z, sensor axes) about TREF = {drift.reference_c:.2f} degC, the log's",
        f"#   mean; OFF is the offset there (X0 = 0); a flight's {high - low:.1f} degC determine a straight line",
        "#   only: X2 = X3 = 0; PX4 clips T to [TMIN, TMAX] = the log's range, so the line is not extrapolated",
    ]
    if not np.all(significant):
        zeros = ", ".join("xyz"[i] for i in range(3) if not significant[i])
        comments.append(f"#   {zeros}: within {SIGNIFICANCE:g} one-sigmas of zero, written as 0")
    comments += [
        "# check it is applied: PX4 1.14 and older ignore TC_M*; in every PX4 source magfit could read,",
        "#   TemperatureCompensation::update_offsets_mag computes and publishes the offset (sensor_correction) but",
        "#   calibration::Magnetometer::Correct (src/lib/sensor_calibration/Magnetometer.hpp) does not subtract it;",
        f"#   where it is ignored this calibration holds at TREF and is off by up to {1000 * at_stake:.1f} mG at",
        "#   TMIN/TMAX (compare sensor_mag with vehicle_magnetometer at two temperatures)",
    ]
    return SlotParameters(slot, parameters, comments)
