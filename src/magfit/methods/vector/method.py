"""``method="vector"``: calibration against a reference field, ``raw = G r + V`` (docs/methods.md, "vector").

``r`` is the field expected at each sample in the vehicle frame (the Earth's field rotated by the vehicle's
attitude); G is a general 3x3 matrix, the soft iron times the magnetometer's misalignment (a mirror for a
sensor with left-handed axes), V the hard iron. The calibration returned is ``frame="vehicle"``:
``matrix = G⁻¹`` (absolute: the corrected samples equal the reference, in its unit), ``offset = V``,
``field_strength`` the reference's median magnitude. The equations::

    raw_k = G r_k + V                                   (1)  the model
    raw(t) = G r(t + τ) + V                             (2)  with the attitude's lag τ (time_s given)
    M raw_k − c = r_k,        M = G⁻¹, c = M V          (3)  (1) solved for the field: the vector equations
    d_k · (M raw_k − c) = s,  d_k = −a_k / |a_k|        (4)  the gravity equations (accel given)

(4): where the accelerometer sees gravity alone (:func:`magfit.gravity.still_samples`), its down direction
``d_k`` and the calibrated field make the constant angle of the field's inclination, ``s = B sin δ``.

**Without accel**: linear least squares of (1) on the design ``[r, 1]``, one regression per axis of ``raw``
(Vasconcelos et al., IEEE TAES 47(2), 2011, and Kok & Schön, IEEE Sensors J. 16(14), 2016, fit the same model
by maximum likelihood). The attitude's error makes ``r`` noisy, an errors-in-variables problem whose shrinkage
of G is of order ``σ_a²``, negligible; what limits any estimator is that the error wanders: its mean over the
recording, ``σ_a √(2τ_c/T)`` per axis for a correlation time τ_c over a recording of length T, is
indistinguishable from a turned mounting. An error θ in roll or pitch turns the field's vertical part into the
horizontal plane, so that mean tilt costs ``tan δ · θ̄`` in heading: the floor is ``√(ψ̄² + (tan δ · θ̄)²)``.
(The variants tried against it, and why least squares is kept: docs/methods.md, "vector".)

**With accel**: the joint fit of (3) and (4) at the lag found from (2), linear in (M, c, s). (3) is taken in
the frame of ``r_k``: its radial component ``r̂_k · (M raw_k − c) = |r_k|`` is free of the attitude's error (a
small rotation of r changes its direction, not its length: the magnitude equation, linearised), its two
tangential components carry it. Each kind of equation is weighted by its own noise and time correlation,
``w = 1 / (σ² κ)``, σ² the residuals' scatter and κ how far their batch means exceed independent errors'
(:func:`.equations._inflation`): first from the regression's residuals and the sensors' noise, then from the joint fit's
own residuals, with Huber weights on the gravity equations (accelerations the still-sample gate let through).
Both kinds have noise in their regressors (the magnetometer's in ``raw``, the accelerometer's in ``d``): least
squares would shrink M along what the motion leaves weak to fit it, so its expected contribution is taken off
the normal equations (adjusted least squares, :meth:`.equations._Equations.normal`; the noises from third differences of
the samples, :func:`.equations._noise_sigma`). The uncertainty is a block jackknife of the joint fit
(:data:`magfit.diagnostics.reference.BLOCKS` stretches, each refitted exactly), plus the accelerometer's
calibration prior (:func:`.gravity._tilt_prior`).

What each kind pins. The tangential components give the rotation about the vertical (the heading), with the
attitude's error. The gravity equations (4) see the calibrated field's component along gravity: they pin the
response of the vehicle's vertical output to the horizontal field (M's row z) through the horizontal field
turning under it as the vehicle holds still at different headings; the joint fit is made only when the still
samples' headings spread across both horizontal axes (:data:`.gravity.MIN_HEADING_SPREAD`). Neither pins the response of
the horizontal outputs to the vertical field (M's column z): on a vehicle that tilts little the vertical field
hardly changes in the vehicle frame, so in (3) and (4) alike it is confounded with the offset. The radial
equations pin it: the field's length does change with the tilt, and they carry no attitude error.

What the gravity equations cannot check: they align the magnetometer to the accelerometer, biases included
(an offset b tilts its vertical by b / g; a frame mounted off the vehicle's by its angle). Three guards:

- without ``time_s`` and ``gyro`` the still-sample gate sees |a| alone, and a coordinated turn keeps |a| at g
  while it tilts the apparent vertical: the gravity equations are left out, said in the note;
- a vertical that disagrees with the reference's is refused (:func:`.gravity._vertical_disagreement`, a
  Hausman test against :data:`.gravity.VERTICAL_CHI2`, and :data:`.gravity.MAX_RESIDUAL_GROWTH`): the fit is
  the regression, and the verdict's weaknesses name the accelerometer;
- what no test can see (an offset that moves the vertical by no more than the attitude's error does) is in the
  stated one-sigma: ``accel_sigma`` propagated through the joint fit (:func:`.gravity._tilt_prior`).

**The lag** (``time_s`` given) is searched on a grid of one sample period within ``±max_lag_s``, then refined
by a bounded scalar minimisation of the residual sum of squares, the reference interpolated in time
(:func:`.lag.estimate_lag`); the lag joins the parameters of the uncertainty (the reference's rate is its column of
the design). A best lag at the edge of the grid is not an estimate: the search widens, doubling, up to
:data:`.lag.WIDEST_LAG` times ``max_lag_s`` (and a quarter of the recording), and a lag still at the edge is refused.

One module per step: :mod:`.reference` (the reference checked), :mod:`.lag` (2), :mod:`.regression` (1) by
least squares, :mod:`.equations` and :mod:`.gravity` (3) and (4), :mod:`.judge` (the verdict);
:func:`fit_vector` runs them in that order.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..._validation import check_rows
from ...calibration import Calibration
from ...errors import OptionError
from ..registry import FitInput, fit_input, register
from .gravity import ACCEL_SIGMA, STANDARD_GRAVITY, _gravity_fit
from .judge import _judged
from .lag import _lag
from .reference import _field, _reference_array
from .regression import _regression

#: Fewest samples a vector fit takes: 12 parameters (13 with a lag), and the batch-means covariance needs 80.
MIN_SAMPLES = 80


@register(
    "vector",
    min_samples=MIN_SAMPLES,
    data="samples",
    summary="soft iron × misalignment (a general matrix into the vehicle frame), hard iron and the attitude's lag, "
    "by least squares against a reference field",
    needs=("reference",),
)
def fit_vector(
    data: FitInput,
    *,
    reference: ArrayLike | None = None,
    time_s: ArrayLike | None = None,
    max_lag_s: float = 1.0,
    accel: ArrayLike | None = None,
    gyro: ArrayLike | None = None,
    accel_sigma: float = ACCEL_SIGMA,
) -> Calibration:
    """Fit ``raw = G r + V`` against the reference field ``r`` (see the module docstring).

    Parameters
    ----------
    reference : array_like, shape (N, 3)
        The field expected at each sample in the vehicle frame, in the samples' unit.
    time_s : array_like, shape (N,), optional
        Sample times in seconds (strictly increasing). Given, the lag between the reference and the samples
        is estimated within ``±max_lag_s`` and the fit made at it; not given, none is assumed.
    max_lag_s : float
        The largest lag searched, seconds.
    accel : array_like, shape (N, 3), optional
        The accelerometer's specific force at each sample in the reference's (vehicle) frame, any unit. Given,
        its gravity equations (4) join the fit where it sees gravity alone (:func:`magfit.gravity.still_samples`):
        ``calibration.vector.gravity`` says on how many samples and why the others were left out.
    gyro : array_like, shape (N, 3), optional
        Body rates in rad/s in the same frame, for the still-sample gate (only with ``accel``; without it
        unused, said in ``details["gyro_note"]``). One that looks like degrees per second (the reference turns
        57 times slower than it says) is refused.
    accel_sigma : float
        The accelerometer's calibration one-sigma in m/s² (each axis): its cost in the calibration (the gravity
        equations take the accelerometer's vertical as the truth) is added to the stated uncertainty. 0 for none.
    """
    raw = fit_input(data, "vector").require_samples("vector")
    ref, field, acc, rates = _inputs(raw, reference, max_lag_s, accel, gyro, accel_sigma)
    details: dict[str, Any] = {}
    if rates is not None and acc is None:  # compare() and the pipeline pass every stream a method takes
        details["gyro_note"] = "gyro= is used only with accel= (to find where the accelerometer sees gravity alone)"
    lag = _lag(raw, ref, time_s, max_lag_s, acc, rates, details)
    g, offset = _regression(lag.raw, lag.reference, field)
    gravity = None
    if acc is not None:
        gravity = _gravity_fit(raw, lag.kept, lag.raw, lag.reference, acc, rates, lag.times, g, offset,
                               float(accel_sigma))  # fmt: skip
    return _judged(lag, g, offset, field, gravity, details)


def _inputs(raw: NDArray[np.float64], reference: ArrayLike | None, max_lag_s: float, accel: ArrayLike | None,
            gyro: ArrayLike | None, accel_sigma: float) -> tuple[NDArray[np.float64], float,
            NDArray[np.float64] | None, NDArray[np.float64] | None]:  # fmt: skip
    """The reference (N, 3), its median magnitude, the accelerometer and the gyro, checked."""
    n = raw.shape[0]
    ref = _reference_array(reference, n)
    if not max_lag_s > 0:
        raise OptionError(f"max_lag_s must be a positive number of seconds, got {max_lag_s!r}")
    if not (isinstance(accel_sigma, (int, float)) and 0 <= accel_sigma < STANDARD_GRAVITY):
        raise OptionError(f"accel_sigma must be the accelerometer's calibration one-sigma in m/s², got {accel_sigma!r}")
    frame = "in the reference's (vehicle) frame"
    acc = None if accel is None else check_rows(accel, "accel", n, f"the specific force, any unit, {frame}")
    rates = None if gyro is None else check_rows(gyro, "gyro", n, f"body rates in rad/s, {frame}")
    if acc is not None and np.any(np.all(acc == 0.0, axis=1)):
        row = int(np.argmax(np.all(acc == 0.0, axis=1)))
        raise OptionError(f"accel= is (0, 0, 0) in row {row} (0-based), which has no direction: drop that sample")
    return ref, _field(ref), acc, rates
