"""``method="vector"``: calibration against a reference field, ``raw = G r + V``. The model and its derivation
are in :mod:`.method`; one module per job:

- :mod:`.reference`: the reference field (the Earth's field in the vehicle frame at each sample), checked;
- :mod:`.lag`: the attitude's lag behind the samples, eq. (2);
- :mod:`.regression`: the alignment fit, eq. (1) by least squares;
- :mod:`.equations`, :mod:`.gravity`: with the accelerometer, the joint fit of eq. (3) and (4);
- :mod:`.judge`: the verdict and the calibration;
- :mod:`.tilt`: ``method="tilt"``, against the reference's horizontal strength and vertical component at the logged
  roll and pitch only (the yaw free), with the motors' field.
"""

from __future__ import annotations

from .gravity import GravityFit
from .lag import LagEstimate, estimate_lag
from .method import fit_vector

__all__ = ["GravityFit", "LagEstimate", "estimate_lag", "fit_vector"]
