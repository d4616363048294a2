"""The accelerometer's gravity rows of stage 2 (:mod:`.model`).

Where the accelerometer sees gravity alone (:func:`magfit.gravity.still_samples`, gated on the rates less
stage 1's bias), its down direction ``d_k = −a_k/|a_k|`` and the unit field ``b_k`` make the inclination's
angle, one δ for the whole recording::

    (d_k · b_k − sin δ) / cos δ = 0                                  (2)

(the ``d · (H y − c) = B sin δ`` of the vector methods with ``|b| = 1``): one more residual per sample, δ one
more unknown. It is divided by cos δ because its noise, the accelerometer's direction noise across the
field, is ``σ cos δ`` in ``d · b``: undivided, a fit lowers it by pulling the field towards the vertical.
Its sign is free (δ is fitted), so an accelerometer that reports gravity instead of the specific force fits
alike, with the dip's sign turned. A rotation about a boat's roll axis turns the field about that axis,
which the kinematics cannot tell from the axes' own rotation about it; gravity turns with the boat too, but
the field's angle to it changes with the axes' rotation.

A tilted accelerometer (its bias over g, or its mounting) leaves (2)'s residual as small as a true one and
moves the fitted δ and the axes' rotation instead: the covariance takes it as tilted by an unknown
:data:`ACCEL_BIAS_PRIOR` (``∂(d·b)/∂θ = d × b``), and :mod:`.inclination` checks δ against a given one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..._validation import check_rows
from ...errors import OptionError
from ...gravity import still_samples

#: Fewest samples on which the accelerometer sees gravity alone for the gravity rows to be used.
MIN_GRAVITY_SAMPLES = 50
#: The accelerometer's bias (m/s², over g = 9.81 a tilt of its vertical) and misalignment to the gyroscope taken as
#: unknown in the covariance: a calibrated MEMS accelerometer's residual bias is of this order, and a tilt is
#: invisible in the gravity rows' residual (it moves the fitted dip instead: docs/methods.md, "gyro").
ACCEL_BIAS_PRIOR = 0.07


def _accel(accel: ArrayLike, n: int) -> NDArray[np.float64]:
    """The accelerometer (n, 3), checked; one-line :class:`OptionError` naming what is wrong."""
    a = check_rows(accel, "accel", n, "the specific force in the gyroscope's axes, any unit")
    zero = np.linalg.norm(a, axis=1) == 0
    if np.any(zero):
        raise OptionError(
            f"accel= row {int(np.argmax(zero))} is (0, 0, 0), which has no direction: a missing reading written as "
            "zeros? drop or fill those rows first"
        )
    return a


@dataclass(frozen=True)
class _Gravity:
    """The accelerometer's vertical where it sees gravity alone: stage 2's gravity rows (module docstring).

    ``down`` (n, 3) is ``−a/|a|`` at every sample (unit), ``still`` (n,) where :func:`magfit.gravity.still_samples`
    lets it through, ``weight`` the rows' weight: the magnetometer rows' noise over the gravity rows' (each
    with its correlation in time), so that both are counted in noise units.
    """

    down: NDArray[np.float64]
    still: NDArray[np.bool_]
    weight: float = 1.0
    notes: tuple[str, ...] = ()


def _gravity(a: NDArray[np.float64], y: NDArray[np.float64], w: NDArray[np.float64],
             t: NDArray[np.float64]) -> tuple[_Gravity | None, dict[str, Any]]:  # fmt: skip
    """The gravity rows (module docstring, (2)) from the accelerometer, or None with the reason when too few
    samples see gravity alone; what :func:`magfit.gravity.still_samples` dropped goes to the details."""
    still = still_samples(a, mag=y, gyro=w, time_s=t)
    facts: dict[str, Any] = {"still_samples": int(np.sum(still.keep)), "dropped": still.dropped,
                             "notes": list(still.notes)}  # fmt: skip
    if facts["still_samples"] < MIN_GRAVITY_SAMPLES:
        facts["used"] = False
        dropped = "; ".join(f"{count} {why}" for why, count in still.dropped.items() if count)
        facts["reason"] = (
            f"the accelerometer saw gravity alone on {facts['still_samples']} samples, fewer than "
            f"{MIN_GRAVITY_SAMPLES}, so it was not used (dropped: {dropped or 'none'})"
        )
        return None, facts
    facts["used"] = True
    return _Gravity(-a / np.linalg.norm(a, axis=1)[:, None], still.keep), facts


def _cos(inclination: float) -> float:
    """cos δ, held above 0.1 (a dip beyond 84°, near a magnetic pole, leaves the heading ill-defined anyway)."""
    return max(math.cos(inclination), 0.1)


def _gravity_angle(down: NDArray[np.float64], b: NDArray[np.float64], inclination: float) -> NDArray[np.float64]:
    """(2) as an angle: ``(d · b − sin δ) / cos δ``, to first order the field's dip error in radians.

    Divided by cos δ so that its noise (the accelerometer's direction noise across the field, ``σ cos δ`` in
    ``d · b``) does not depend on δ: undivided, a fit lowers it by pulling the field towards the vertical.
    """
    return np.asarray((np.einsum("ki,ki->k", down, b) - math.sin(inclination)) / _cos(inclination), dtype=np.float64)
