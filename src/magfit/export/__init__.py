"""Firmware exports: write a :class:`magfit.Calibration` in the convention of the code that will use it.

Every target states its own formula in the file it writes, next to how magfit's
``corrected = matrix @ (raw - offset)`` maps onto it; ``docs/exports.md`` has the table.

========== ========== ====================================================== ============
name       extension  convention written                                     values in
========== ========== ====================================================== ============
json       .json      magfit's own, lossless (``Calibration.from_json``)     input unit
c          .h         ``corrected = matrix * (raw - offset)``, C floats       input unit
ardupilot  .param     ``mag += OFS; mag *= SCALE; mag = [DIA/ODI] * mag``    milligauss
px4        .params    ``corrected = S * (raw - OFF)``, S from SCALE/ODIAG    gauss
fusion     .h         ``softIronMatrix * (uncalibrated - hardIronOffset)``   input unit
magcal     .m         MATLAB ``C = (D - b) * A``                              input unit
adafruit   .h         ``softiron * (magnetic - hardiron)``, row-major [9]    µT
adafruit-  .json      the same, Adafruit_Sensor_Calibration_SDFat's file     µT
json
inav       .txt       ``(raw - magzero) * 1024 / maggain`` (diagonal only)   raw counts
betaflight .txt       ``align(raw) - mag_calibration`` (offset only)         raw counts
rtimulib   .ini       ``compassCalCorr * (compass - compassCalOffset)``      µT
ros-       .yaml      ``magnetic_field - mag_bias`` (offset only)            tesla
madgwick
yaml       .yaml      ``corrected = matrix @ (raw - offset)``, generic        input unit
========== ========== ====================================================== ============

>>> import numpy as np, magfit
>>> from magfit.export import export
>>> cal = magfit.Calibration("ellipsoid", np.array([28.6, -40.0, -27.4]), np.eye(3), 52.9, unit="uT")
>>> print(export(cal, "ardupilot").splitlines()[-10])
COMPASS_OFS_X,-286
"""

from .registry import FORMATS, MOTOR_FORMATS, SEVERAL, UNIT_CHECKED, FormatSpec, export, export_several

__all__ = ["FORMATS", "MOTOR_FORMATS", "SEVERAL", "UNIT_CHECKED", "FormatSpec", "export", "export_several"]
