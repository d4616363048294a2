"""The magnetometer's rotation into the vehicle's frame, from gravity and the field's inclination, no attitude.

A magnitude-only calibration (every ``magfit.fit`` method with ``frame="sensor"``) leaves the corrected field
in the magnetometer's own axes. The firmware must also know how those axes sit in the vehicle (ArduPilot
``COMPASS_ORIENT``, PX4 ``CAL_MAGn_ROT``, Betaflight/INAV ``align_mag``). The accelerometer gives it without
any attitude estimate: wherever the vehicle is, the angle between gravity and the Earth's field is the same,
90° minus the inclination δ. With ``m_k`` the calibrated field (magnetometer frame) and ``a_k`` the
accelerometer's specific force (body frame) at sample k, and ``d_k = −a_k / |a_k|`` the downward direction
(the accelerometer reads the specific force, which points *up*: about (0, 0, −g) in a level
forward-right-down body; the field points down in the northern magnetic hemisphere, δ > 0)::

    d_kᵀ R m_k / |m_k| = sin δ          for every sample k                                 (A1)

R (``body = R @ sensor``, the firmwares' convention, :mod:`magfit.rotations`) is fitted by a robust (Huber)
Levenberg-Marquardt over rotations from the 24 axis-aligned starts (and their 24 mirror images), with δ
known (the World Magnetic Model, :mod:`magfit.geomag`) or fitted as a fourth parameter.

What the samples determine. Turning R by a small angle θ (body frame) changes (A1) by ``θ · (R m̂_k × d_k)``:
each sample constrains only the rotation about its *magnetic east* direction ``m̂ × d`` (normal to the plane of
the field and gravity). A rotation about the field, about gravity or any axis in their plane leaves that
sample's dip unchanged. R is determined only when the east directions of the samples span the three body
axes. A level vehicle turning in yaw has d = body z always, so its east directions all lie in the body x-y
plane: the mount's roll and pitch are determined, its yaw (rotation about body z) is not, whatever the
number of samples. A boat rolling on a steady heading sees east near one body direction in a plane; the
rotation about the axis normal to that plane is weakly determined. The information matrix ``Σ w_k j_k j_kᵀ``,
``j_k = R m̂_k × d_k``, gives those directions and their one-sigma; a rotation axis with a one-sigma beyond
:data:`UNDETERMINED_SIGMA_DEG` is refused (``CalibrationError``) naming it, one beyond
:data:`WEAK_SIGMA_DEG` is weak. Two traps of that local view: the lever ``RMS(j_k · n)`` of an axis made of
the accelerometer's noise alone still gives a sigma that falls as 1/√N (below 1.5 noise levels the axis is
refused as not determined), and a lever shorter than :data:`SHORT_LEVER` (3° of tilt) magnifies any bias of
the apparent gravity beyond what the sigma counts (weak, named). The loss is also scanned along each axis
for another angle that fits as well.

The accelerometer sees gravity alone only when the vehicle does not accelerate (:mod:`magfit.gravity`):
samples are kept where ``|a|`` is within :data:`ACCEL_TOLERANCE` of g (the median |a| of the samples that turn
slowly) and the vehicle's heading turns slower than ``max_rate_dps`` (with a gyroscope; without one, the rate
at which the field and gravity directions turn): in a turn at speed v and rate ω the centripetal acceleration
v ω tilts the apparent gravity by ``atan(v ω / g)`` (0.75° at 25 m/s and the default 0.3°/s), and a
coordinated turn hides it from |a| entirely. Rolling and pitching (a boat in waves) accelerate a sensor only
through its lever arm and are kept up to ``max_tilt_rate_dps``. Kept samples are averaged over half
a second. Remaining outliers are down-weighted (Huber).

Mirrors. A magnetometer whose axes are left-handed relative to the body (one axis inverted, or two swapped)
is an orthogonal R with det −1 that no firmware rotation can represent; it is fitted as such and reported
with the sensor axis to invert. Without a known inclination, R with δ and −R with −δ fit (A1) alike: the
field is then taken to point down (δ > 0, the northern magnetic hemisphere), and the mirror verdict rests
on that. An accelerometer that reports gravity instead of the specific force (its sign inverted) also looks
like a mirror: −R is proper, and both readings are reported. Gravity directions that keep to a plane (a level
vehicle, one that only pitches) cannot tell a rotation from its reflection across that plane: right-handed
axes are then assumed and the result is weak, saying so (``allow_mirror=True`` refuses instead).

The one-sigma is honest for correlated samples: batch means of the score over contiguous blocks of the
recording (the sandwich covariance, as in :func:`magfit.diagnostics.uncertainty.correlation_excess`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._scale import robust_scale
from ._validation import check_inclination
from .errors import CalibrationError, OptionError, SampleError
from .findings import Reason
from .gravity import ACCEL_TOLERANCE, MAX_RATE_DPS, MAX_TILT_RATE_DPS, moving_mean, still_samples
from .remedy import option
from .rotations import (
    FIRMWARES,
    StandardRotation,
    angle_between_deg,
    axis_words,
    euler_angles,
    nearest_rotation,
    polar_decomposition,
    signed_permutations,
    skew,
)

__all__ = ["ACCEL_TOLERANCE", "Alignment", "FirmwareRotation", "align", "nearest_rotations"]

#: Fewest samples the fit needs after the gates.
MIN_SAMPLES = 50
#: A rotation axis determined worse than this (one-sigma, degrees) is refused; worse than WEAK is weak.
UNDETERMINED_SIGMA_DEG = 10.0
WEAK_SIGMA_DEG = 1.0
#: A rotation whose lever on the dips (RMS of ``(R m̂ × d)·n``, radians) is shorter than this is weak: sin 3°.
SHORT_LEVER = math.sin(math.radians(3.0))
#: RMS dip residual (degrees) beyond which the samples' scatter is named (1° of accelerometer noise gives about 1°).
LARGE_RESIDUAL_DEG = 3.0
#: An inclination fitted worse than this (one-sigma, degrees) is not determined.
INCLINATION_UNDETERMINED_DEG = 10.0
#: A given inclination is refused when it fits worse than the samples' own dip by a likelihood ratio of
#: INCLINATION_CHI2 (five one-sigmas) and differs from it by more than INCLINATION_SIGMAS times the reference
#: model's error (the World Magnetic Model's, about 0.3° RMS).
INCLINATION_CHI2 = 25.0
#: ... a disagreement beyond this (degrees) is refused; within it, the rotation's one-sigma is widened by it
#: (an uncalibrated accelerometer: the real MPU-9250 recording shows 64.3° where the model says 68.5°).
INCLINATION_REFUSE_DEG = 5.0
INCLINATION_SIGMAS = 3.0
INCLINATION_MODEL_DEG = 0.3
#: Contiguous blocks of the recording for the batch-means covariance.
_BATCHES = 20
#: Samples fitted from each of the 48 starts before the best is refined on all of them.
_START_SAMPLES = 800
_AXES = "xyz"


@dataclass(frozen=True)
class FirmwareRotation:
    """The firmware's table entry nearest to the fitted rotation.

    Attributes
    ----------
    firmware : str
        ``"ardupilot"``, ``"px4"``, ``"betaflight"`` or ``"inav"``.
    rotation : StandardRotation
        The entry (``id`` is the parameter value) with ``angle_deg``, the angle between it and the fit.
    parameter : str
        The parameter that selects it (``COMPASS_ORIENT``, ``CAL_MAG0_ROT``, ``align_mag``).
    """

    firmware: str
    rotation: StandardRotation
    parameter: str


@dataclass(frozen=True, eq=False)
class Alignment:
    """The magnetometer's rotation into the accelerometer's (vehicle's) frame: ``body = matrix @ sensor``.

    Attributes
    ----------
    matrix : ndarray, shape (3, 3)
        Orthogonal; det +1, or −1 for a mirror (:attr:`mirror`).
    roll_deg, pitch_deg, yaw_deg : float
        The 3-2-1 angles of the rotation (``Rz(yaw) Ry(pitch) Rx(roll)``, the firmwares' sequence); for a
        mirror, of ``matrix @ diag`` with :attr:`inverted_axis` negated.
    sigma_deg : ndarray, shape (3,)
        One-sigma of roll, pitch, yaw, degrees (batch means over the recording: correlated samples counted).
    axis_sigma_deg : ndarray, shape (3,)
        One-sigma of a small rotation about body x, y, z, degrees.
    inclination_deg, inclination_sigma_deg : float
        The field's inclination used: given (sigma 0) or fitted.
    inclination_fitted : bool
    mirror : bool
        det(matrix) = −1: the sensor's axes are left-handed relative to the body.
    inverted_axis : str or None
        For a mirror, the sensor axis (``"x"``, ``"y"``, ``"z"``) whose sign to invert so that a proper rotation
        (the nearest standard one being the closest) remains.
    nearest : tuple of FirmwareRotation
        The nearest table entry of each firmware (of the proper part for a mirror).
    residual_deg : float
        RMS of the dip residuals of the samples used, degrees (``asin(dᵀ R m̂) − δ``).
    n_samples, n_used : int
        Samples given, samples used in the fit.
    dropped : dict
        Why the others were left out, in words -> count.
    verdict : str
        ``"supported"`` or ``"weak"`` (a refusal raises :class:`~magfit.CalibrationError`, unless
        ``allow_undetermined``, then ``"refused"``).
    warnings : tuple of str
        What is refused, then what is weak, in words; then notes on the gates (no time stamps ...).
    """

    matrix: NDArray[np.float64]
    roll_deg: float
    pitch_deg: float
    yaw_deg: float
    sigma_deg: NDArray[np.float64]
    axis_sigma_deg: NDArray[np.float64]
    inclination_deg: float
    inclination_sigma_deg: float
    inclination_fitted: bool
    mirror: bool
    inverted_axis: str | None
    nearest: tuple[FirmwareRotation, ...]
    residual_deg: float
    n_samples: int
    n_used: int
    dropped: dict[str, int] = field(default_factory=dict)
    verdict: str = "supported"
    warnings: tuple[str, ...] = ()

    @property
    def proper_matrix(self) -> NDArray[np.float64]:
        """The rotation left once :attr:`inverted_axis` is negated (``matrix`` itself when not a mirror)."""
        return self.matrix @ _flip(self.inverted_axis)

    def nearest_for(self, firmware: str) -> FirmwareRotation:
        """The nearest table entry of ``firmware``."""
        for entry in self.nearest:
            if entry.firmware == firmware:
                return entry
        raise OptionError(f"unknown firmware {firmware!r}; valid firmwares: {', '.join(FIRMWARES)}")


# --- small rotation algebra -------------------------------------------------------------------------------


def _exp(theta: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rodrigues: the rotation by |θ| about θ."""
    angle = float(np.linalg.norm(theta))
    k = skew(theta)
    if angle < 1e-12:
        return np.eye(3) + k
    return np.eye(3) + math.sin(angle) / angle * k + (1.0 - math.cos(angle)) / angle**2 * (k @ k)


def _flip(axis: str | None) -> NDArray[np.float64]:
    d = np.ones(3)
    if axis is not None:
        d[_AXES.index(axis)] = -1.0
    return np.diag(d)


#: A rotation axis of the body frame in words (:func:`magfit.rotations.axis_words`).
_BODY_AXES = (
    "body x (forward; the mount's roll)",
    "body y (right; the mount's pitch)",
    "body z (down; the mount's yaw)",
)


def _axis_words(axis: NDArray[np.float64]) -> str:
    return axis_words(axis, "body", names=_BODY_AXES, within_deg=20.0, noun="axis", unsigned=True)


# --- the gates ----------------------------------------------------------------------------------------------


# --- the fit ------------------------------------------------------------------------------------------------


@dataclass
class _Solution:
    matrix: NDArray[np.float64]  # orthogonal, possibly a mirror
    s: float  # sin δ
    cost: float  # median squared residual of (A1): comparable between solutions, unlike a robust loss's scale


def _huber_weights(r: NDArray[np.float64], scale: float) -> NDArray[np.float64]:
    k = 1.345 * scale
    a = np.abs(r)
    return np.where(a <= k, 1.0, k / np.maximum(a, 1e-300))


def _huber_loss(r: NDArray[np.float64], scale: float) -> float:
    k = 1.345 * scale
    a = np.abs(r)
    return float(np.sum(np.where(a <= k, 0.5 * a**2, k * a - 0.5 * k**2)))


def _robust_scale(r: NDArray[np.float64]) -> float:
    return max(robust_scale(r)[1], 1e-6)


def _residuals(down: NDArray[np.float64], mhat: NDArray[np.float64], matrix: NDArray[np.float64], s: float
               ) -> NDArray[np.float64]:  # fmt: skip
    """(A1)'s residuals ``dᵀ R m̂ − sin δ``."""
    return np.einsum("ij,ij->i", down, mhat @ matrix.T) - s


def _solve(
    down: NDArray[np.float64],
    mhat: NDArray[np.float64],
    start: NDArray[np.float64],
    s0: float,
    fit_s: bool,
    iterations: int = 30,
) -> _Solution:
    """Robust Levenberg-Marquardt on (A1) from ``start`` (Huber, its scale re-estimated each step); the
    rotation is updated on the left, in the body frame."""
    matrix, s = start.copy(), s0
    damping = 1e-3
    for _ in range(iterations):
        x = mhat @ matrix.T  # the field in the body frame
        r = np.einsum("ij,ij->i", down, x) - s
        scale = _robust_scale(r)
        w = _huber_weights(r, scale)
        jac = np.cross(x, down)  # d r / d θ = x × d, for R -> exp([θ]×) R
        if fit_s:
            jac = np.column_stack([jac, -np.ones(len(r))])
        h = jac.T @ (w[:, None] * jac)
        grad = jac.T @ (w * r)
        cost = _huber_loss(r, scale)
        while damping <= 1e6:
            step = -np.linalg.solve(h + damping * np.diag(np.diag(h) + 1e-12), grad)
            trial = _exp(step[:3]) @ matrix
            trial_s = s + (float(step[3]) if fit_s else 0.0)
            if _huber_loss(_residuals(down, mhat, trial, trial_s), scale) <= cost:
                matrix, s, damping = trial, trial_s, max(damping / 10.0, 1e-9)
                break
            damping *= 10.0
        else:
            break
        if np.linalg.norm(step) < 1e-10:
            break
    matrix = polar_decomposition(matrix)[0]  # keep it orthogonal against rounding
    return _Solution(matrix, float(s), float(np.median(_residuals(down, mhat, matrix, s) ** 2)))


def _covariance(
    down: NDArray[np.float64], mhat: NDArray[np.float64], solution: _Solution, fit_s: bool
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], float]:
    """(covariance of (θ, [s]), information matrix, residuals, how many times the batch means widen the
    independent-sample variance): Gauss-Newton σ² H⁻¹ widened by batch means."""
    x = mhat @ solution.matrix.T
    r = np.einsum("ij,ij->i", down, x) - solution.s
    scale = _robust_scale(r)
    w = _huber_weights(r, scale)
    jac = np.cross(x, down)
    if fit_s:
        jac = np.column_stack([jac, -np.ones(len(r))])
    k = jac.shape[1]
    h = jac.T @ (w[:, None] * jac)
    variance = float(np.sum(w * r**2) / max(np.sum(w) - k, 1.0))
    h_inv = np.linalg.pinv(h)
    cov = variance * h_inv
    # Batch means of the score over contiguous blocks (Flegal & Jones 2010; the sandwich of White 1982): the
    # samples of a recording are not independent, a block's sum of scores spreads as much as it really does.
    batches = min(_BATCHES, len(r) // 10)
    if batches >= 4:
        scores = jac * (w * r)[:, None]
        edges = np.linspace(0, len(r), batches + 1).astype(np.int64)
        sums = np.add.reduceat(scores, edges[:-1], axis=0)
        sums -= sums.mean(axis=0)
        sandwich = h_inv @ (sums.T @ sums * batches / (batches - 1)) @ h_inv
        values, vectors = np.linalg.eigh(sandwich - cov)
        widened = cov + (vectors * np.clip(values, 0.0, None)) @ vectors.T
        inflation = float(np.trace(widened) / max(np.trace(cov), 1e-300))
        return widened, h / variance, r, inflation
    return cov, h / variance, r, 1.0


def _euler_sigma(matrix: NDArray[np.float64], cov_theta: NDArray[np.float64]) -> NDArray[np.float64]:
    """One-sigma of (roll, pitch, yaw) in degrees, by a numerical Jacobian of the 3-2-1 angles."""
    base = np.array(euler_angles(matrix))
    jac = np.empty((3, 3))
    eps = 1e-6
    for i in range(3):
        d = np.zeros(3)
        d[i] = eps
        diff = np.array(euler_angles(_exp(d) @ matrix)) - base
        jac[:, i] = (diff + 180.0) % 360.0 - 180.0
    jac /= eps
    return np.sqrt(np.clip(np.diag(jac @ cov_theta @ jac.T), 0.0, None))


def _check_array(values: ArrayLike, name: str, n: int | None = None) -> NDArray[np.float64]:
    array = np.asarray(values, dtype=np.float64)
    if array.ndim != 2 or array.shape[1] != 3:
        raise SampleError(f"{name} must have shape (N, 3), got {array.shape}")
    if n is not None and array.shape[0] != n:
        raise SampleError(f"{name} has {array.shape[0]} rows but the magnetometer has {n}: give one row per sample")
    if not np.all(np.isfinite(array)):
        raise SampleError(f"{name} contains NaN or inf values")
    return array


def _mirror_axis(matrix: NDArray[np.float64]) -> tuple[str, tuple[FirmwareRotation, ...]]:
    """The sensor axis whose inversion leaves the proper rotation nearest to ArduPilot's table (the
    tables share their 90° entries), and the nearest entries of that rotation."""
    best: tuple[float, str, tuple[FirmwareRotation, ...]] | None = None
    for axis in _AXES:
        nearest = nearest_rotations(matrix @ _flip(axis))
        angle = nearest[0].rotation.angle_deg
        if best is None or angle < best[0] - 1e-6:
            best = (angle, axis, nearest)
    assert best is not None
    return best[1], best[2]


_PARAMETERS = {"ardupilot": "COMPASS_ORIENT", "px4": "CAL_MAG0_ROT", "betaflight": "align_mag", "inav": "align_mag"}


def nearest_rotations(rotation: NDArray[np.float64]) -> tuple[FirmwareRotation, ...]:
    """The nearest table entry of each firmware to the proper rotation ``rotation`` (``body = rotation @ sensor``)."""
    return tuple(
        FirmwareRotation(firmware, nearest_rotation(rotation, firmware), _PARAMETERS[firmware])
        for firmware in FIRMWARES
    )


def align(
    calibrated_mag: ArrayLike,
    accel: ArrayLike,
    *,
    inclination_deg: float | None = None,
    gyro: ArrayLike | None = None,
    time_s: ArrayLike | None = None,
    max_rate_dps: float | None = MAX_RATE_DPS,
    max_tilt_rate_dps: float = MAX_TILT_RATE_DPS,
    accel_tolerance: float = ACCEL_TOLERANCE,
    allow_mirror: bool | None = None,
    allow_undetermined: bool = False,
) -> Alignment:
    """The rotation of the magnetometer into the accelerometer's frame, from gravity and the inclination (A1).

    Parameters
    ----------
    calibrated_mag : array_like, shape (N, 3)
        The field corrected by a magnitude-only calibration (``cal.apply(raw)``), magnetometer axes, any unit.
        The one-sigma takes that calibration as exact: an error in its vertical part turns every dip alike
        (from a weak ``auto`` fit on a car, 5° off at a stated ±0.9°); ``magfit align`` caps the verdict at the
        calibration's own and starts from the gyro-aided fit's magnitude-only part where it has a gyroscope.
    accel : array_like, shape (N, 3)
        The accelerometer's specific force at the same instants, in the body (vehicle) frame, any unit
        (gravity reads about (0, 0, −1 g) in a level forward-right-down body).
    inclination_deg : float, optional
        The field's inclination δ, positive downwards (the World Magnetic Model: :func:`magfit.geomag.field_at`).
        Fitted when not given, which needs the vehicle tilted; the field is then taken to point down.
    gyro : array_like, shape (N, 3), optional
        Body rates in rad/s: samples turning about the vertical faster than ``max_rate_dps``, or about the
        horizontal axes faster than ``max_tilt_rate_dps``, are left out (:mod:`magfit.gravity`).
    time_s : array_like, shape (N,), optional
        Sample times in seconds: without a gyroscope, the rate is that of the field and gravity directions.
    max_rate_dps : float or None
        Fastest rotation (°/s, averaged over about a second) of a sample used; None keeps every rate (a
        hand-held rotation about the sensor itself, which has no centripetal acceleration to speak of).
    accel_tolerance : float
        Largest relative deviation of |a| from g (the median |a| of the samples that turn slowly) of a sample used.
    allow_mirror : bool or None
        Whether a mirror image (det −1) of the sensor's axes may be the answer. None (default): yes where the
        samples can tell; where they cannot (a vehicle that stays nearly level), the proper rotation is returned
        as weak, the assumption named. True: a mirror must be ruled in or out (refused when the samples cannot).
        False: the axes are known to be right-handed.
    allow_undetermined : bool
        Return a refused alignment (``verdict="refused"``, the reason first in ``warnings``) instead of raising.

    Returns
    -------
    Alignment

    Raises
    ------
    SampleError
        Malformed arrays (shape, rows, NaN), a zero accelerometer or field.
    OptionError
        An inclination, tolerance or rate out of range.
    CalibrationError
        Too few samples see gravity alone; a rotation axis (or the fitted inclination) the samples do not
        determine, named; two distinct rotations that fit alike.
    """
    mag = _check_array(calibrated_mag, "calibrated_mag")
    n = mag.shape[0]
    acc = _check_array(accel, "accel", n)
    rates = None if gyro is None else _check_array(gyro, "gyro", n)
    times = None
    if time_s is not None:
        times = np.asarray(time_s, dtype=np.float64)
        if times.shape != (n,) or not np.all(np.isfinite(times)):
            raise SampleError(f"time_s must be {n} finite times (seconds), got shape {times.shape}")
    if inclination_deg is not None:
        inclination_deg = check_inclination(inclination_deg)
    if not 0.0 < accel_tolerance < 1.0:
        raise OptionError(f"accel_tolerance must be within (0, 1), got {accel_tolerance}")
    if max_rate_dps is not None and not max_rate_dps > 0:
        raise OptionError(f"max_rate_dps must be positive (or None), got {max_rate_dps}")
    if not max_tilt_rate_dps > 0:
        raise OptionError(f"max_tilt_rate_dps must be positive, got {max_tilt_rate_dps}")
    norm_m = np.linalg.norm(mag, axis=1)
    if np.any(norm_m <= 0):
        raise SampleError("calibrated_mag has zero rows: a field of zero has no direction")

    down, mhat, direction_noise, dropped, notes = _still_directions(
        mag, acc, rates, times, max_rate_dps, max_tilt_rate_dps, accel_tolerance
    )
    fit_s = inclination_deg is None
    s0 = math.sin(math.radians(inclination_deg)) if inclination_deg is not None else 0.0

    search_mirrors = allow_mirror is not False
    solutions = _search(down, mhat, s0, fit_s, search_mirrors)
    best = solutions[0]
    cov, info, residuals, inflation = _covariance(down, mhat, best, fit_s)
    refusals, weak = _judge_axes(down, mhat, best, cov, info, inflation, direction_noise, fit_s)

    inclination = math.degrees(math.asin(max(-1.0, min(1.0, best.s))))
    inclination_sigma = 0.0
    if fit_s:
        cosine = max(math.cos(math.radians(inclination)), 1e-9)
        inclination_sigma = math.degrees(math.sqrt(max(float(cov[3, 3]), 0.0)) / cosine)
        _, unbiased, _ = _dip_fit(down, mhat, best.matrix, math.radians(inclination), True)
        allowed = INCLINATION_SIGMAS * max(inclination_sigma, INCLINATION_MODEL_DEG)
        if abs(math.degrees(unbiased) - inclination) > allowed:
            # The robust fit of dᵀ R m̂ − sin δ is pulled towards the vertical where the samples hardly pin δ.
            refusals.append(Reason(
                f"the inclination is not determined: fitted {inclination:.1f}° ± {inclination_sigma:.1f}°, but "
                f"{math.degrees(unbiased):.1f}° with the residual taken as a dip angle (the samples leave the dip and "
                "a tilt of the mount about magnetic east nearly interchangeable: a vehicle on one heading); give "
                f"the inclination (the World Magnetic Model at your place: {option('location', 'LAT,LON')})",
                "inclination",
                (("inclination_deg", "the World Magnetic Model's"),),
            ))  # fmt: skip
        elif inclination_sigma > INCLINATION_UNDETERMINED_DEG:
            refusals.append(
                f"the inclination is not determined (fitted {inclination:.1f}° ± {inclination_sigma:.0f}°): "
                "record more tilt, or give the inclination (the World Magnetic Model at your place: "
                f"{option('location', 'LAT,LON')})"
            )
    refusals += _judge_alternatives(down, mhat, solutions, residuals, inflation, direction_noise, search_mirrors)
    if not fit_s and inclination_deg is not None:
        disagreement = _inclination_disagreement(down, mhat, best, inclination_deg)
        if disagreement is not None:
            reason, difference = disagreement
            if abs(difference) > INCLINATION_REFUSE_DEG:
                refusals.append(reason)
            else:  # widened: a wrong δ is taken up by a tilt of the mount of up to as much
                weak.append(Reason(f"{reason}; the one-sigma of the rotation includes {abs(difference):.1f}° for it",
                                   "inclination", reason.remedy))  # fmt: skip
                cov = cov.copy()
                cov[:3, :3] += math.radians(difference) ** 2 * np.eye(3)
    if allow_mirror is None and _MIRROR_REFUSAL in refusals:
        # The samples cannot tell: right-handed axes, by far the commoner, are assumed and the result says so.
        right_handed = align(
            calibrated_mag, accel, inclination_deg=inclination_deg, gyro=gyro, time_s=time_s,
            max_rate_dps=max_rate_dps, max_tilt_rate_dps=max_tilt_rate_dps, accel_tolerance=accel_tolerance,
            allow_mirror=False,
            allow_undetermined=allow_undetermined,
        )  # fmt: skip
        assumed = (
            "these samples cannot tell a rotation from a mirror image of the sensor's axes (gravity stays near one "
            "body plane): right-handed axes are assumed; if the sensor's axes may be left-handed, record it tilted "
            "in several attitudes"
        )
        return replace(
            right_handed,
            verdict="weak" if right_handed.verdict == "supported" else right_handed.verdict,
            warnings=(*right_handed.warnings, assumed),
        )

    mirror = bool(np.linalg.det(best.matrix) < 0)
    if mirror:
        inverted, nearest = _mirror_axis(best.matrix)
        weak.append(_mirror_warning(best.matrix, inverted, nearest[0].rotation, fit_s))
    else:
        inverted, nearest = None, nearest_rotations(best.matrix)
    proper = best.matrix @ _flip(inverted)
    roll, pitch, yaw = euler_angles(proper)
    # Flipping a sensor axis is a reflection on the right, which does not change the body-frame θ.
    axis_sigma = np.degrees(np.sqrt(np.clip(np.diag(cov[:3, :3]), 0.0, None)))
    euler_sigma = _euler_sigma(proper, cov[:3, :3])
    dips = np.degrees(np.arcsin(np.clip(residuals + best.s, -1.0, 1.0))) - inclination
    residual_deg = float(np.sqrt(np.mean(dips**2)))
    if residual_deg > LARGE_RESIDUAL_DEG:
        weak.append(
            f"the dip angles scatter by {residual_deg:.1f}° RMS: an accelerometer not calibrated (offsets, scales), "
            "accelerations left in the samples used, or a magnetometer calibration that does not fit them; the "
            "one-sigma counts this scatter, not a bias it may hide"
        )
    verdict = "refused" if refusals else "weak" if weak else "supported"
    if refusals and not allow_undetermined:
        first = refusals[0]
        raise CalibrationError(
            f"the alignment is refused: {first}",
            codes=(first.code,) if isinstance(first, Reason) else ("undetermined",),
            remedy=first.remedy if isinstance(first, Reason) else (),
        )
    return Alignment(
        matrix=best.matrix,
        roll_deg=roll,
        pitch_deg=pitch,
        yaw_deg=yaw,
        sigma_deg=euler_sigma,
        axis_sigma_deg=axis_sigma,
        inclination_deg=inclination,
        inclination_sigma_deg=inclination_sigma,
        inclination_fitted=fit_s,
        mirror=mirror,
        inverted_axis=inverted,
        nearest=nearest,
        residual_deg=residual_deg,
        n_samples=n,
        n_used=len(down),
        dropped=dropped,
        verdict=verdict,
        warnings=tuple(refusals + weak + notes),
    )


def _dip_fit(down: NDArray[np.float64], mhat: NDArray[np.float64], start: NDArray[np.float64], dip: float,
             free: bool, iterations: int = 20) -> tuple[NDArray[np.float64], float, NDArray[np.float64]]:  # fmt: skip
    """Gauss-Newton on (A1) as a dip error, ``(dᵀ R m̂ − sin δ) / cos δ`` (radians), plain least squares from
    (``start``, ``dip``), δ fitted when ``free``: (R, δ, residuals).

    Divided by cos δ, its noise (the directions' noise across the field, ``σ cos δ`` in ``dᵀ R m̂``) does not
    depend on δ; undivided, a fit with δ free lowers it by pulling the field towards the vertical.
    """
    matrix = start.copy()
    for _ in range(iterations):
        x = mhat @ matrix.T
        cosine = max(math.cos(dip), 0.1)
        r = (np.einsum("ij,ij->i", down, x) - math.sin(dip)) / cosine
        jac = np.cross(x, down) / cosine
        if free:
            jac = np.column_stack([jac, -1.0 + math.tan(dip) * r])
        step = -np.linalg.lstsq(jac, r, rcond=None)[0]
        matrix = _exp(step[:3]) @ matrix
        dip += float(step[3]) if free else 0.0
        if np.linalg.norm(step) < 1e-10:
            break
    matrix = polar_decomposition(matrix)[0]
    cosine = max(math.cos(dip), 0.1)
    return matrix, dip, (np.einsum("ij,ij->i", down, mhat @ matrix.T) - math.sin(dip)) / cosine


def _inclination_disagreement(down: NDArray[np.float64], mhat: NDArray[np.float64], best: _Solution,
                              given_deg: float) -> tuple[Reason, float] | None:  # fmt: skip
    """The reason and the difference (degrees, the samples' dip less the given one) when the dip the samples
    show disagrees with the inclination given, else None.

    A wrong δ is otherwise absorbed by a tilt of R (a boat given 30° for 64°: the mount 34° off at a stated
    ±0.3°). (A1) as a dip error (:func:`_dip_fit`) is fitted with δ given and with δ free, from the fit at
    the given δ; the given one is refused when it fits worse by a likelihood ratio of
    :data:`INCLINATION_CHI2` (the residuals' correlation in time counted, batch means) and differs from the
    samples' own dip by more than :data:`INCLINATION_MODEL_DEG` times :data:`INCLINATION_SIGMAS` (the
    reference model's error). A likelihood ratio, not the free dip's one-sigma: a boat on one heading leaves
    the dip and the tilt about magnetic east a flat valley whose local one-sigma means nothing.
    """
    dip = math.radians(given_deg)
    _, _, held = _dip_fit(down, mhat, best.matrix, dip, False)
    _, fitted, free = _dip_fit(down, mhat, best.matrix, dip, True)
    n = len(free)
    variance = float(np.sum(free**2)) / max(n - 4, 1)
    batches = min(_BATCHES, n // 10)
    inflation = 1.0
    if batches >= 4:
        edges = np.linspace(0, n, batches + 1).astype(np.int64)
        means = np.add.reduceat(free, edges[:-1]) / np.diff(edges)
        inflation = max(1.0, float(np.var(means, ddof=1)) * (n / batches) / max(float(np.mean(free**2)), 1e-300))
    ratio = (float(np.sum(held**2)) - float(np.sum(free**2))) / max(variance * inflation, 1e-300)
    difference = math.degrees(fitted) - given_deg
    if ratio <= INCLINATION_CHI2 or abs(difference) <= INCLINATION_SIGMAS * INCLINATION_MODEL_DEG:
        return None
    reason = Reason(
        f"the samples put the field's dip at {math.degrees(fitted):.1f}° (the angle between gravity and the field), "
        f"where inclination_deg= says {given_deg:.1f}° ({difference:+.1f}°; the given one fits worse by a likelihood "
        f"ratio of {ratio:.0f}): a wrong inclination is taken up by a tilt of the mount; check the inclination (the "
        "World Magnetic Model at the place of the recording) and the accelerometer's and magnetometer's "
        "calibrations, or leave inclination_deg out to fit it",
        "inclination",
        (("inclination_deg", "None"),),
    )
    return reason, difference


def _still_directions(
    mag: NDArray[np.float64],
    acc: NDArray[np.float64],
    gyro: NDArray[np.float64] | None,
    time_s: NDArray[np.float64] | None,
    max_rate_dps: float | None,
    max_tilt_rate_dps: float,
    accel_tolerance: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64], float, dict[str, int], list[str]]:
    """The down and field directions (d, m̂) of the samples on which the accelerometer sees gravity alone,
    the accelerometer's direction noise on them (radians), why the others were dropped, and notes.

    Raises
    ------
    CalibrationError
        Fewer than :data:`MIN_SAMPLES` are left.
    """
    n = len(mag)
    gate = still_samples(
        acc, mag=mag, gyro=gyro, time_s=time_s, max_rate_dps=max_rate_dps, max_tilt_rate_dps=max_tilt_rate_dps,
        accel_tolerance=accel_tolerance,
    )  # fmt: skip
    keep, dropped, notes, width = gate.keep, gate.dropped, list(gate.notes), gate.width
    dropped = {reason: count for reason, count in dropped.items() if count}
    n_used = int(np.sum(keep))
    if n_used < MIN_SAMPLES:
        reasons = "; ".join(f"{count} {reason}" for reason, count in dropped.items()) or "none"
        raise CalibrationError(
            f"only {n_used} of {n} samples see gravity alone (dropped: {reasons}); the alignment needs at least "
            f"{MIN_SAMPLES}: record the vehicle held still or moved slowly in several attitudes"
            + ("" if max_rate_dps is None else ", or allow faster turns (max_rate_dps) if it turned about itself")
        )
    # The accelerometer's direction noise (radians, from successive differences of still samples): tilt
    # within it carries no information about the rotations, only noise that looks like some.
    raw_down = -acc / np.linalg.norm(acc, axis=1, keepdims=True)
    pairs = keep[1:] & keep[:-1]
    steps = np.linalg.norm(np.diff(raw_down, axis=0)[pairs], axis=1) if np.any(pairs) else np.zeros(1)
    half = max(1, width // 2)
    direction_noise = math.sqrt(float(np.mean(steps**2)) / 4.0) / math.sqrt(half)
    if half > 1:
        # Averaged over half a second of samples that turn slower than max_rate_dps (0.15° at 0.3°/s): the
        # accelerometer's noise would otherwise read as tilt.
        acc = np.column_stack([moving_mean(acc[:, i], half) for i in range(3)])
        mag = np.column_stack([moving_mean(mag[:, i], half) for i in range(3)])
    down = -acc[keep] / np.linalg.norm(acc[keep], axis=1, keepdims=True)
    mhat = mag[keep] / np.linalg.norm(mag[keep], axis=1, keepdims=True)
    return down, mhat, direction_noise, dropped, notes


def _judge_axes(
    down: NDArray[np.float64],
    mhat: NDArray[np.float64],
    best: _Solution,
    cov: NDArray[np.float64],
    info: NDArray[np.float64],
    inflation: float,
    direction_noise: float,
    fit_s: bool,
) -> tuple[list[str], list[str]]:
    """(refusals, weaknesses) of the rotation about each eigen-direction of the information about θ."""
    refusals: list[str] = []
    weak: list[str] = []
    info_theta = info[:3, :3]
    if fit_s and info[3, 3] > 0:  # the information left about θ once δ is fitted too (Schur complement)
        info_theta = info_theta - np.outer(info[:3, 3], info[3, :3]) / info[3, 3]
    values, vectors = np.linalg.eigh(info_theta)
    lever_arms = np.cross(mhat @ best.matrix.T, down)
    for value, vector in zip(values, vectors.T, strict=True):
        sigma = math.degrees(1.0 / math.sqrt(value)) if value > 0 else math.inf
        sigma = max(sigma, math.degrees(math.sqrt(max(float(vector @ cov[:3, :3] @ vector), 0.0))))
        # The lever of this rotation on the dips; against the noise of gravity's direction it is made of noise
        # (its sigma then falls as 1/√N all the same: a level vehicle would "determine" its mount's yaw).
        lever = math.sqrt(float(np.mean((lever_arms @ vector) ** 2)))
        if lever < 1.5 * direction_noise:
            sigma = math.inf
        # Far along this axis (the sigma is local): another angle that fits as well leaves it undetermined.
        far = _far_minimum(down, mhat, best, vector, inflation)
        if far is not None:
            sigma = max(sigma, far)
        if sigma > UNDETERMINED_SIGMA_DEG:
            level = (
                " (a level vehicle turning in yaw sees gravity on body z only: its roll and pitch of the mount are "
                "determined, its yaw is not)"
                if abs(vector[2]) > 0.9
                else ""
            )
            refusals.append(
                f"the rotation about {_axis_words(vector)} is not determined (one-sigma "
                f"{'beyond 180' if sigma > 180 else f'{sigma:.0f}'}°): each sample pins only the rotation about its "
                "magnetic east (normal to gravity and the field), and these samples' east directions do not reach "
                f"that axis{level}; record the vehicle tilted (rolled and pitched) in several headings, or give the "
                "mount's rotation"
            )
        elif sigma > WEAK_SIGMA_DEG:
            weak.append(f"the rotation about {_axis_words(vector)} is weakly determined (one-sigma {sigma:.1f}°)")
        elif lever < SHORT_LEVER:
            # The one-sigma counts the noise; a bias of the apparent gravity (the edge of a coordinated turn, an
            # accelerometer offset) is magnified by 1/lever, and no scatter shows it (docs/methods.md).
            weak.append(
                f"the rotation about {_axis_words(vector)} is seen through only {math.degrees(lever):.1f}° of tilt: "
                f"its one-sigma ({sigma:.2f}°) counts the noise, not a bias of the apparent gravity (turns, the "
                f"accelerometer's offsets), which this lever magnifies {1.0 / lever:.0f} times"
            )
    return refusals, weak


_MIRROR_REFUSAL = (
    "these samples cannot tell a rotation from a mirror image of the sensor's axes (gravity stays near one body "
    "axis: a reflection across a plane that holds it changes no dip angle); record the vehicle tilted in several "
    "attitudes, or state that the axes are right-handed (allow_mirror=False)"
)


def _judge_alternatives(
    down: NDArray[np.float64],
    mhat: NDArray[np.float64],
    solutions: list[_Solution],
    residuals: NDArray[np.float64],
    inflation: float,
    direction_noise: float,
    allow_mirror: bool,
) -> list[str]:
    """Refusals for a mirror image or another rotation the samples cannot tell from the best fit."""
    refusals: list[str] = []
    if allow_mirror:
        # A reflection across the plane the gravity directions keep to changes each dip by 2 (d·n)(n·R m̂): with
        # d·n within a few times the accelerometer's noise, whatever the fit prefers is noise or bias (a wrong
        # mirror is a sign flip, so three noise levels rather than the rotations' 1.5).
        moments = np.linalg.eigvalsh(down.T @ down / len(down))
        if math.sqrt(max(float(moments[0]), 0.0)) < 3.0 * direction_noise:
            refusals.append(_MIRROR_REFUSAL)
    # Another minimum that fits as well: compared by the Huber loss at the best fit's scale, as a chi-square
    # with the correlation of the samples counted (25: five one-sigmas).
    best = solutions[0]
    scale = _robust_scale(residuals)
    best_loss = _huber_loss(residuals, scale)
    for other in solutions[1:]:
        excess = 2.0 * (_huber_loss(_residuals(down, mhat, other.matrix, other.s), scale) - best_loss) / scale**2
        if excess >= 25.0 * inflation:
            continue
        if np.linalg.det(other.matrix) * np.linalg.det(best.matrix) < 0:
            if _MIRROR_REFUSAL not in refusals:
                refusals.append(_MIRROR_REFUSAL)
            break
        angle = _relative_angle(best.matrix, other.matrix)
        if angle > 5.0:  # two starts that refined onto the same minimum are one
            refusals.append(
                f"two rotations {angle:.0f}° apart fit these samples alike: record the vehicle in more attitudes"
            )
            break
    return refusals


def _mirror_warning(matrix: NDArray[np.float64], inverted: str, nearest: StandardRotation, fit_s: bool) -> str:
    """A mirror in words, with its two readings: a sensor axis to invert, or an accelerometer to negate."""
    flipped = nearest_rotation(-matrix, "ardupilot")  # -R is proper: (A1) with d -> -d
    return (
        f"the magnetometer's axes are a mirror image of the body's (det -1): no firmware rotation can fix it; "
        f"invert its {inverted} axis (in the driver or the wiring), then the rotation is "
        f"{nearest.name} + {nearest.angle_deg:.1f}°; or the accelerometer reports gravity instead of the specific "
        "force (its sign inverted"
        + (", or the field points up: the southern magnetic hemisphere" if fit_s else "")
        + f"), and the rotation is {flipped.name} + {flipped.angle_deg:.1f}° once the accelerometer is negated"
    )


def _far_minimum(
    down: NDArray[np.float64], mhat: NDArray[np.float64], best: _Solution, axis: NDArray[np.float64], inflation: float
) -> float | None:
    """The largest angle (degrees, beyond 10°) of a rotation of the best fit about ``axis`` (body frame) whose
    loss is within chance of the best (a chi-square of 25, widened by the samples' correlation), or None."""
    r = _residuals(down, mhat, best.matrix, best.s)
    scale = _robust_scale(r)
    best_loss = _huber_loss(r, scale)
    worst = None
    for angle in np.arange(10.0, 351.0, 5.0):
        turned = _exp(np.radians(angle) * axis) @ best.matrix
        excess = 2.0 * (_huber_loss(_residuals(down, mhat, turned, best.s), scale) - best_loss) / scale**2
        if excess < 25.0 * inflation:
            distance = min(angle, 360.0 - angle)
            worst = distance if worst is None else max(worst, distance)
    return worst


def _relative_angle(a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
    """Angle (degrees) between two orthogonal matrices of the same handedness; 180 for opposite handedness."""
    if np.linalg.det(a) * np.linalg.det(b) < 0:
        return 180.0
    return angle_between_deg(
        a @ _flip("z") if np.linalg.det(a) < 0 else a, b @ _flip("z") if np.linalg.det(b) < 0 else b
    )


def _search(
    down: NDArray[np.float64], mhat: NDArray[np.float64], s0: float, fit_s: bool, allow_mirror: bool
) -> list[_Solution]:
    """Distinct minima of (A1), best first: 48 starts (24 rotations, 24 mirrors) on a stride of the samples,
    the best three and the best of the other handedness then refined on all of them."""
    stride = max(1, len(down) // _START_SAMPLES)
    d_sub, m_sub = down[::stride], mhat[::stride]
    start_s = s0 if not fit_s else 0.5
    found: list[_Solution] = []
    for start in signed_permutations():
        for handed in (np.eye(3), _flip("z")) if allow_mirror else (np.eye(3),):
            found.append(_solve(d_sub, m_sub, start @ handed, start_s, fit_s, iterations=15))
    found = [_northern(f, fit_s, allow_mirror) for f in found]
    found.sort(key=lambda f: f.cost)
    distinct: list[_Solution] = []
    for candidate in found:
        if all(_relative_angle(candidate.matrix, other.matrix) > 5.0 for other in distinct):
            distinct.append(candidate)
    chosen = distinct[:3]
    handedness = {bool(np.linalg.det(c.matrix) < 0) for c in chosen}
    chosen += [c for c in distinct if bool(np.linalg.det(c.matrix) < 0) not in handedness][:1]
    if allow_mirror:
        # The reflections of the best fit across the planes the gravity directions keep to (the principal
        # planes of their scatter) and the body's: a vehicle that stays level or pitches only fits them as
        # well, and a start may miss their minimum.
        _, principal = np.linalg.eigh(down.T @ down)
        for normal in (*principal.T, *np.eye(3)):
            mirror = np.eye(3) - 2.0 * np.outer(normal, normal)
            chosen.append(_Solution(mirror @ chosen[0].matrix, chosen[0].s, math.inf))
    refined = [_northern(_solve(down, mhat, c.matrix, c.s, fit_s), fit_s, allow_mirror) for c in chosen]
    refined.sort(key=lambda f: f.cost)
    return refined


def _northern(solution: _Solution, fit_s: bool, allow_mirror: bool) -> _Solution:
    """With δ fitted, R with δ and −R with −δ fit alike: the field is taken to point down (δ > 0). Without
    mirrors, −R is not a candidate and δ keeps the sign the fit gives it."""
    if fit_s and allow_mirror and solution.s < 0:
        return _Solution(-solution.matrix, -solution.s, solution.cost)
    return solution
