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

from ..errors import CalibrationError
from ..statistics import Statistics


def ellipsoid_outline_problem(statistics: Statistics) -> str | None:
    """Why the best algebraic quadric through the samples is no ellipsoid, or None when it is one."""
    from ..geometry.quadric import quadric_ellipsoid

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
            "sensor through all attitudes, away from moving magnets",
            codes=("no_ellipsoid",),
        )
