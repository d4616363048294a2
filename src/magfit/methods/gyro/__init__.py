"""Gyro-aided calibration (``method="gyro"``): hard and soft iron and the magnetometer's axes from the rotation
kinematics, without a tumble. The model and its derivation are in :mod:`.method`; one module per job:

- :mod:`.rates`: the gyro, its times and their units, and the other readings of them the kinematics prefer;
- :mod:`.windows`: stage 1, the kinematics integrated over windows (linear in the correction);
- :mod:`.kinematics`: the body's rotation integrated from the rates;
- :mod:`.model`: stage 2, maximum likelihood over stretches, and its covariance;
- :mod:`.gravity`, :mod:`.inclination`: the accelerometer's rows, their weight and the dip they fit;
- :mod:`.mapping`, :mod:`.choice`: stage 3, the standard axis mappings and the one the samples choose;
- :mod:`.lag`: the magnetometer's delay behind the gyroscope;
- :mod:`.judge`: what the motion determines, the verdict.
"""

from __future__ import annotations

from .mapping import MAPPINGS, mapping_name
from .method import fit_gyro

__all__ = ["MAPPINGS", "fit_gyro", "mapping_name"]
