"""The gravity rows' weight and the dip they fit, checked against the reference model's.

Both kinds of row count in noise units: the gravity rows' weight is ``√(σ²_mag κ_mag / σ²_grav κ_grav)``,
each the residuals' variance times their correlation in time (the variance of five-second batch means times
the batch length over the plain variance, :func:`.model._effective_variance`), from the general fit without
the rows and once more with them (:func:`_weighted`).

(2) of :mod:`.gravity` sees the accelerometer's tilt about the magnetic east-west axis only
(``∂(d·b)/∂θ = d × b``), and that tilt moves δ: a fitted dip that differs from ``inclination_deg=`` (the World
Magnetic Model's) by more than :data:`INCLINATION_SIGMAS` times its one-sigma and
:data:`INCLINATION_MODEL_DEG` combined means the accelerometer's calibration or alignment is off, and its
rows are dropped (:func:`_inclination_disagreement`). Magnitudes are compared: the dip's sign is the
accelerometer's convention and the magnetometer's handedness, which the kinematics leave free.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from .gravity import _Gravity, _gravity_angle
from .model import _covariance, _effective_variance, _Model, _noise_variance

#: The reference inclination's own error (the World Magnetic Model's is about 0.3° RMS, more near anomalies),
#: and how many combined one-sigmas a fitted dip may differ from a given one before the accelerometer is
#: taken to disagree (with its calibration or its alignment to the gyroscope) and its rows are dropped.
INCLINATION_MODEL_DEG = 0.3
INCLINATION_SIGMAS = 2.0


def _gravity_residual(model: _Model, gravity: _Gravity) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """The gravity rows' residual (unweighted, radians) on the still rows of a model's trajectory, and those
    rows; δ from the mean of d_k · b_k when the model has no gravity rows of its own."""
    traj, p = model.traj, model.solution.params
    b = traj.field(p)[0]
    still = gravity.still[traj.rows]
    down = gravity.down[traj.rows][still]
    if traj.gravity is not None:
        inclination = float(p[traj.k + 6])
    else:
        inclination = math.asin(float(np.clip(np.mean(np.einsum("ki,ki->k", down, b[still])), -0.99, 0.99)))
    return _gravity_angle(down, b[still], inclination), traj.rows[still]


def _weighted(model: _Model, gravity: _Gravity) -> _Gravity:
    """The gravity rows weighted by the model's magnetometer noise over their own (each its effective
    variance, correlation in time included): both kinds of row then count in noise units."""
    residual, rows = _gravity_residual(model, gravity)
    variance = _effective_variance(residual[:, None], model.traj.t[rows], 1)
    return replace(gravity, weight=math.sqrt(_noise_variance(model) / max(variance, 1e-300)))


def _dip(model: _Model, covariance: NDArray[np.float64] | None = None) -> dict[str, float]:
    """The fitted inclination and its one-sigma (degrees) of a model with gravity rows.

    The calibrated field is ``sign · b`` with the sign that makes the correction proper (fit_gyro), so its dip
    is ``sign · δ``.
    """
    traj, p = model.traj, model.solution.params
    covariance = _covariance(traj, p) if covariance is None else covariance
    sign = float(np.sign(np.linalg.det(traj.distortion(p))))
    return {
        "inclination_deg": sign * math.degrees(float(p[traj.k + 6])),
        "inclination_sigma_deg": math.degrees(math.sqrt(max(float(covariance[traj.k + 6, traj.k + 6]), 0.0))),
    }


def _inclination_disagreement(model: _Model, given_deg: float) -> str | None:
    """Why the accelerometer disagrees with the given inclination, or None when it agrees.

    Magnitudes are compared: the dip's sign is the accelerometer's convention (specific force or gravity) and
    the magnetometer's handedness, which the kinematics leave free. A tilted accelerometer leaves its rows'
    residual as small as a true one (the tilt moves the fitted dip instead), so this is its only check.
    """
    dip = _dip(model)
    fitted, sigma = dip["inclination_deg"], dip["inclination_sigma_deg"]
    difference = abs(fitted) - abs(given_deg)
    allowed = INCLINATION_SIGMAS * math.hypot(sigma, INCLINATION_MODEL_DEG)
    if abs(difference) <= allowed:
        return None
    return (
        f"the accelerometer's gravity puts the field's dip at {abs(fitted):.1f}° ± {sigma:.1f}°, where "
        f"inclination_deg= says {abs(given_deg):.1f}° ({difference:+.1f}°, beyond the {allowed:.1f}° allowed): its "
        "calibration (a bias) or its alignment to the gyroscope is off, so its rows were not used"
    )


#: The field's dip against the accelerometer's down (the sine of it, the median over the samples) that tells
#: the field's sense: nearer the horizontal (within about 15°) its sign is not read.
HANDEDNESS_MIN_SINE = 0.26
#: ... and the share of samples whose sine must have the median's sign (a vehicle's accelerations aside).
HANDEDNESS_AGREEMENT = 0.8


def _mirror_fix(matrix: NDArray[np.float64]) -> str:
    """The one change of the magnetometer's columns (an axis negated, or two swapped) that makes a mirrored
    correction ``−matrix`` nearest the gyroscope's own axes: what to tell the user to do."""
    from .mapping import MAPPINGS, mapping_name

    mirrored = -MAPPINGS[mapping_name(matrix)]
    changes: dict[str, NDArray[np.float64]] = {}
    for i in range(3):
        flip = np.eye(3)
        flip[i, i] = -1.0
        changes[f"negate m{'xyz'[i]}"] = flip
    for i, j in ((0, 1), (0, 2), (1, 2)):
        swap = np.eye(3)[:, [j if k == i else i if k == j else k for k in range(3)]]
        changes[f"swap m{'xyz'[i]} and m{'xyz'[j]}"] = swap
    return min(changes, key=lambda name: float(np.linalg.norm(mirrored @ changes[name] - np.eye(3))))


def _field_sense(y: NDArray[np.float64], a: NDArray[np.float64], offset: NDArray[np.float64],
                 matrix: NDArray[np.float64], given_deg: float | None) -> str | None:  # fmt: skip
    """Why the calibrated field points the wrong way (a mirrored magnetometer), or None.

    The kinematics fit ``H`` and ``−H`` alike (:mod:`.method`), so a magnetometer whose axes are left-handed
    against the gyroscope's (two swapped, one negated) is calibrated as the proper correction with the field
    reversed: every heading 180° off. The accelerometer's down ``d_k = −a_k/|a_k|`` (its specific force: up at
    rest) tells the field's sense: ``d_k · b_k = sin δ``, positive where the field points down (the northern
    hemisphere) and of the sign of ``inclination_deg=`` when given. The median over all samples, not only the
    still ones: a vehicle's accelerations tilt ``d`` by tens of degrees, not across the horizontal.
    """
    field = (y - offset) @ matrix.T
    field /= np.linalg.norm(field, axis=1)[:, None]
    down = -a / np.linalg.norm(a, axis=1)[:, None]
    sine = np.einsum("ki,ki->k", down, field)
    median = float(np.median(sine))
    if abs(median) < HANDEDNESS_MIN_SINE or np.mean(np.sign(sine) == np.sign(median)) < HANDEDNESS_AGREEMENT:
        return None
    expected = 1.0 if given_deg is None else math.copysign(1.0, given_deg)
    if given_deg is not None and abs(given_deg) < math.degrees(math.asin(HANDEDNESS_MIN_SINE)):
        return None
    if median * expected > 0:
        return None
    dip = math.degrees(math.asin(median))
    mirrored = (
        "the magnetometer's axes are left-handed against the gyroscope's (the kinematics then fit the field reversed, "
        f"every heading 180° off); {_mirror_fix(matrix)} (or give the axes in the datasheet's order and signs), then "
        "fit again"
    )
    if given_deg is None:  # the field up: a mirror in the north, or a right-handed sensor in the south
        return (
            f"the calibrated field's dip against the accelerometer's down is {dip:+.0f}° (the field points up) and no "
            f"inclination_deg= was given to tell the hemisphere: either {mirrored}, or the recording was made in the "
            "southern hemisphere, where the field points up: give inclination_deg= (negative there; the World "
            "Magnetic Model's at the place). If the accelerometer reports gravity rather than the specific force, "
            "negate it"
        )
    return (
        f"the calibrated field's dip against the accelerometer's down is {dip:+.0f}° where inclination_deg= says "
        f"{given_deg:+.0f}°: {mirrored}. If the accelerometer reports gravity rather than the specific force, negate it"
    )
