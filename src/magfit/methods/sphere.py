"""The paper's hard-iron-only calibration (section III): linear least squares on eq. (7).

With W = I the model (6) is a sphere ``|x − V|² = B²``, linear in ``(2V, B² − |V|²)``:
``[x y z 1] · (2Vx, 2Vy, 2Vz, B² − |V|²) = x² + y² + z²`` (eq. 7, with the factor 2 the text lost).
"""

from __future__ import annotations

import numpy as np

from ..calibration import Calibration
from ..errors import CalibrationError
from .registry import FitInput, register


@register(
    "sphere",
    min_samples=4,
    data="statistics",
    summary="hard iron only: least-squares sphere fit (paper, section III)",
)
def fit_sphere(data: FitInput) -> Calibration:
    """Solve eq. (7) by least squares; the calibration is ``raw − V`` on a sphere of radius B (eq. 8)."""
    statistics = data.statistics
    scatter = statistics.scatter
    # Normal equations of eq. (7) read off the scatter: u = (z, 1) is design entries 6..9 and
    # |z|² the sum of entries 0..2.
    normal = scatter[6:10, 6:10]
    right = scatter[6:10, 0:3].sum(axis=1)
    solution = np.linalg.solve(normal, right)
    centre_z = 0.5 * solution[:3]
    radius_squared_z = float(solution[3] + centre_z @ centre_z)
    if not radius_squared_z > 0:
        raise CalibrationError(
            "the sphere fit found no real sphere (B² <= 0): the samples do not outline a sphere; "
            "check that they are magnetometer readings taken while turning the sensor"
        )
    return Calibration(
        method="sphere",
        offset=statistics.centre + statistics.scale * centre_z,
        matrix=np.eye(3),
        field_strength=statistics.scale * np.sqrt(radius_squared_z),
        n_samples=statistics.n,
    )
