"""The heading error a target leaves when it can hold only part of a calibration.

Some targets store less than magfit fits (INAV: a diagonal; Betaflight and imu_filter_madgwick: the
offset only; PX4 keeps its old value of a term that changes by less than 0.01). The files say what
that costs, as a compass heading error, computed here for the calibration at hand.

The model: magfit's corrected field ``f`` has length ``B`` (``field_strength``) and the raw sample
is ``raw = matrix⁻¹ f + offset`` (the calibration inverted). The target computes
``g = M' (raw - o')`` with its own ``M'`` and ``o'``. For a sensor held level with its z axis
vertical, the heading is ``atan2(y, x)`` of the horizontal components; the error is the largest
``|heading(g) - heading(f)|`` over all headings and over field inclinations up to
:data:`MAX_INCLINATION_DEG` either way (the vertical field leaks into x and y through ``M'``, so
steep fields cost more). A real mounting that is not level changes the figure; it is a measure of
the loss, not a flight prediction.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..calibration import Calibration

#: Field inclinations covered: up to 70 deg north or south (most inhabited places).
MAX_INCLINATION_DEG = 70.0
#: The assumption the figure rests on, for the files' comments.
ASSUMPTION = f"sensor level with z vertical, field inclination up to {MAX_INCLINATION_DEG:.0f} deg"


def heading_error_deg(calibration: Calibration, matrix: ArrayLike, offset: ArrayLike) -> float:
    """The worst heading error (degrees) of ``matrix @ (raw - offset)`` against ``calibration.apply``.

    Parameters
    ----------
    calibration : Calibration
        The full calibration (the reference).
    matrix : array_like, shape (3, 3)
        The correcting matrix the target applies, in the calibration's convention.
    offset : array_like, shape (3,)
        The offset the target subtracts, in the calibration's unit.

    Returns
    -------
    float
        The largest absolute heading difference, in degrees (see the module docstring).
    """
    target_matrix = np.asarray(matrix, dtype=np.float64)
    target_offset = np.asarray(offset, dtype=np.float64)
    return heading_error_of(calibration, lambda raw: (raw - target_offset) @ target_matrix.T)


def heading_error_of(calibration: Calibration, correct: Callable[[NDArray[np.float64]], NDArray[np.float64]]) -> float:
    """The worst heading error (degrees) of a target's own correction against ``calibration.apply``.

    ``correct`` maps raw samples (N, 3), in the calibration's unit, to the target's corrected vectors (N, 3),
    in its own arithmetic (integers, truncation); the grid of fields is that of :func:`heading_error_deg`.
    """
    inclinations = np.radians(np.linspace(-MAX_INCLINATION_DEG, MAX_INCLINATION_DEG, 29))
    headings = np.radians(np.arange(0.0, 360.0, 0.5))
    inc, head = np.meshgrid(inclinations, headings, indexing="ij")
    directions = np.stack([np.cos(inc) * np.cos(head), np.cos(inc) * np.sin(head), np.sin(inc)], axis=-1)
    field: NDArray[np.float64] = calibration.field_strength * directions.reshape(-1, 3)
    raw = np.linalg.solve(calibration.matrix, field.T).T + calibration.offset
    seen = correct(raw)
    error = np.arctan2(seen[:, 1], seen[:, 0]) - np.arctan2(field[:, 1], field[:, 0])
    error = (error + np.pi) % (2.0 * np.pi) - np.pi
    return float(np.degrees(np.max(np.abs(error))))
