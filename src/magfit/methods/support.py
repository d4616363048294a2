"""Can these samples support a calibration at all? Checks shared by the paper's methods.

Beyond the checks every fit gets (:func:`magfit._validation.check_support`: enough samples, not
identical, not flat), the sphere and min/max methods ask one more question: do the samples outline an
ellipsoid? Any hard- and soft-iron distortion maps the field's sphere onto an ellipsoid (eq. 2). When
the best-fitting quadric is a hyperboloid, the samples cover too few directions or the distortion
changed during the recording, and a sphere or min/max fit to them would be numbers without meaning
(the ellipsoid method refuses such data by itself). Weaker problems, such as an offset that the
attitudes visited determine only poorly, are reported by the diagnostics, not refused here.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ..errors import CalibrationError
from ..statistics import Statistics


def solve_sphere(statistics: Statistics) -> tuple[NDArray[np.float64], float, NDArray[np.float64]]:
    """Least-squares sphere of eq. (7) in the normalised frame of ``statistics``.

    Returns
    -------
    centre_z : ndarray, shape (3,)
        Centre in the normalised frame.
    radius_squared_z : float
        B² in the normalised frame (may be <= 0 when the samples outline no sphere).
    centre_covariance_z : ndarray, shape (3, 3)
        Covariance of the centre, from the residual variance of eq. (7).
    """
    scatter = statistics.scatter
    # Normal equations of eq. (7) read off the scatter: u = (z, 1) is design entries 6..9 and
    # |z|² the sum of entries 0..2.
    normal = scatter[6:10, 6:10]
    right = scatter[6:10, 0:3].sum(axis=1)
    solution = np.linalg.lstsq(normal, right, rcond=None)[0]
    centre_z = 0.5 * solution[:3]  # eq. (7) solves for 2V
    radius_squared_z = float(solution[3] + centre_z @ centre_z)
    sum_r4 = float(scatter[0:3, 0:3].sum())  # Σ |z|⁴
    residual_sum = max(sum_r4 - 2.0 * solution @ right + solution @ normal @ solution, 0.0)
    variance = residual_sum / max(statistics.n - 4, 1)
    covariance = variance * np.linalg.pinv(normal)
    return centre_z, radius_squared_z, covariance[:3, :3] / 4.0


def ellipsoid_outline_problem(statistics: Statistics) -> str | None:
    """Why the best algebraic quadric through the samples is no ellipsoid, or None when it is one."""
    from .quadric import quadric_ellipsoid

    eigenvectors = np.linalg.eigh(statistics.scatter)[1]
    reason = quadric_ellipsoid(eigenvectors[:, 0], statistics)
    return reason if isinstance(reason, str) else None


def check_outlines_ellipsoid(statistics: Statistics, method: str) -> None:
    """Raise :class:`CalibrationError` when the best algebraic quadric through the samples is no ellipsoid."""
    reason = ellipsoid_outline_problem(statistics)
    if reason is not None:
        raise CalibrationError(
            f"the samples do not outline an ellipsoid ({reason}), as "
            "every hard- and soft-iron distortion should: they cover too few directions, or the distortion "
            f"changed while recording; the {method} fit to them would mean nothing. Record again turning the "
            "sensor through all attitudes, away from moving magnets"
        )
