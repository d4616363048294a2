"""One vehicle's compasses against each other: their relative rotation, the firmwares' pre-arm figures, advice.

A vehicle with two or three compasses measures one field. Once each compass is calibrated (its offset
removed and its lengths corrected, eq. (1) undone), the field vectors the compasses report at the same
instant differ only by the rotation between their frames, by noise, and by whatever disturbs one of them
and not the other (the motors' current near an internal compass)::

    b_j(t) = R_ij b_i(t) + e(t)                                                               (C1)

where ``b_i`` is compass i's calibrated field in the body frame its *declared* orientation gives
(ArduPilot's ``COMPASS_ORIENT*``, PX4's ``CAL_MAGn_ROT``). Two correctly mounted compasses have
``R_ij = I`` within a few degrees of mounting tolerance.

**The rotation** (Wahba's problem, solved by the SVD; Kabsch 1976, Markley 1988): with
``H = Σ_k b_i(t_k) b_j(t_k)ᵀ = U S Vᵀ``, the rotation minimising ``Σ_k |b_j - R b_i|²`` is::

    R_ij = V diag(1, 1, det(V Uᵀ)) Uᵀ                                                        (C2)

No centring: the calibrations already removed the offsets, and the mean field direction carries the
information. Only the symmetric part of each calibration matrix is used (``S = sqrtm(Mᵀ M)``,
:func:`magfit.rotations.polar_decomposition`), so a rotation a vector fit folded into its matrix does not
hide the misalignment sought here.

**Its uncertainty.** The samples of a log are correlated in time (the vehicle turns slowly), so the
textbook covariance ``σ² (Σ [b]ₓᵀ[b]ₓ)⁻¹`` is too small. A block jackknife over contiguous stretches of
the log is used instead: with ``K`` blocks, ``δ_b = log(R̂ᵀ R_(−b))`` (the rotation vector of the
leave-one-block-out estimate against the whole), ``Σ_δ = (K−1)/K Σ_b (δ_b − δ̄)(δ_b − δ̄)ᵀ``; the
stated one-sigma of the angle is the square root of Σ_δ's largest eigenvalue, with 0.5° added in quadrature
for what no resampling sees: the calibrations' own errors (a cross term of the symmetric soft-iron matrix 1 %
off turns a vector by up to 0.6°). The rotation about an axis
the field never left is undetermined: the information ``J = (1/N) Σ (I − b̂ b̂ᵀ)`` then has an
eigenvalue near 0 (a vehicle standing still, or level with the field along one body axis).

**Which compass is wrong.** With three compasses, the one whose rotations to both others are large while
the other pair agrees. With two, the relative rotation cannot say which; the attitude's roll and pitch
can (they come from the accelerometer, not from a compass, so a compass that drove the EKF's yaw does not
bias them): a correctly mounted compass keeps a constant angle to the down direction ``d = Aᵀ e_z`` (the
field's inclination), a rotated one does not once the vehicle tilts. The compass whose angle to ``d``
spreads more is named; the corrected orientation is ``M_true = C M_declared`` with ``C`` the rotation that
takes its field onto the other's.

**The current.** The difference ``b_j − R_ij b_i`` is regressed on the battery current (or the throttle)
where the log has it: a slope that the regression determines means one of the two follows the current;
each compass's own field length regressed on it says which.

**The firmwares' pre-arm figures** on the common time stamps (ArduPilot ``Compass::consistent()``,
``AP_Compass.h``; PX4 ``VehicleMagnetometer`` and the commander's magnetometer consistency check):

- ArduPilot, each compass used for yaw against the primary: the 3-D angle (limit
  ``AP_COMPASS_MAX_XYZ_ANG_DIFF`` = 90°), the angle between the horizontal (body x-y) components
  (``AP_COMPASS_MAX_XY_ANG_DIFF`` = 60°), and the length of the difference of the horizontal components
  (``AP_COMPASS_MAX_XY_LENGTH_DIFF`` = 200 mG). Older ArduPilot (3.x) had 50°, 30° and 100 mG.
- PX4: the angle between each of the first two other compasses and the primary, low-pass filtered per
  update (``0.95 a + 0.05 angle``), its maximum compared with ``COM_ARM_MAG_ANG`` (60° in current PX4,
  45° before).

The figures depend on the attitude (a rotation about the vertical turns the horizontal component by its
whole angle and the 3-D vector by less), so each is given over the log: its median and the share of the
time stamps at which the check would fail.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import DataFileError, MagfitError, SampleError
from .findings import Reason, ReasonList
from .remedy import option
from .rotations import StandardRotation, nearest_rotation, polar_decomposition
from .units import conversion_factor, get_unit

if TYPE_CHECKING:
    from .pipeline import FileCalibration

__all__ = [
    "ARDUPILOT_LIMITS",
    "PX4_ANGLE_LIMIT_DEG",
    "ArduPilotFigures",
    "CompassComparison",
    "CompassField",
    "CurrentEffect",
    "Misorientation",
    "PX4Figures",
    "PairRotation",
    "compare_compasses",
    "compare_fields",
    "compass_fields",
    "wahba_rotation",
]

#: ArduPilot's ``Compass::consistent()`` limits (``AP_Compass.h``): 3-D angle (deg), horizontal angle (deg),
#: length of the horizontal difference (mG).
ARDUPILOT_LIMITS = (90.0, 60.0, 200.0)
#: ArduPilot 3.x had these (the same header in 2016-2017).
ARDUPILOT_OLD_LIMITS = (50.0, 30.0, 100.0)
#: PX4's ``COM_ARM_MAG_ANG`` default (degrees; 45 before PX4 1.12).
PX4_ANGLE_LIMIT_DEG = 60.0
#: Added in quadrature to the jackknife's one-sigma: the calibrations' own errors turn the fields too (a symmetric
#: soft-iron matrix 1 % off in a cross term turns a vector by up to 0.6°), which no resampling of the log sees.
SIGMA_FLOOR_DEG = 0.5
#: A relative rotation below this is mounting tolerance, not a wrong orientation (degrees).
MISORIENTED_DEG = 10.0
#: Two compasses whose residual after the best rotation exceeds this share of the field do not measure one field.
DISAGREE = 0.25
#: The nearest table entry is offered as the fix only when it is this close to the orientation found (degrees).
NEAREST_DEG = 5.0
#: A current effect is named when the regression explains this share of the pairwise difference's variance.
CURRENT_R2 = 0.2


@dataclass(frozen=True, eq=False)
class CompassField:
    """One compass's calibrated field on its own time stamps, in the body frame its declared orientation gives.

    Attributes
    ----------
    sensor : str
        The compass's id (``MAG/1``).
    time_s : ndarray, shape (N,)
        Time stamps, seconds (the log's time base).
    field : ndarray, shape (N, 3)
        ``S (raw − offset)`` turned into the body frame by the declared mounting, in ``unit``.
    unit : str
        The field's unit (``mG``, ``G``, or empty when unknown).
    mounting : ndarray (3, 3) or None
        The declared orientation (``body = mounting @ sensor``), None when the log does not say.
    down : ndarray, shape (N, 3), or None
        The down direction in the body frame from the attitude (roll and pitch only), None without attitude.
    slot : int or None
        The firmware's calibration slot (``COMPASS_OFS2`` is 1, ``CAL_MAG1`` is 1).
    device_id : int or None
        The firmware's device id.
    firmware : str or None
        ``"ardupilot"`` or ``"px4"`` when known from the log.
    supported : bool
        The calibration's verdict was "supported" (not weak).
    used_for_yaw : bool
        ArduPilot's ``COMPASS_USEn`` (``Compass::consistent()`` skips a compass not used for yaw).
    """

    sensor: str
    time_s: NDArray[np.float64]
    field: NDArray[np.float64]
    unit: str = ""
    mounting: NDArray[np.float64] | None = None
    down: NDArray[np.float64] | None = None
    slot: int | None = None
    device_id: int | None = None
    firmware: str | None = None
    supported: bool = True
    used_for_yaw: bool = True


@dataclass(frozen=True)
class CurrentEffect:
    """How the difference between two compasses follows the battery current (or the throttle).

    Attributes
    ----------
    regressor : str
        ``"current"`` (A) or ``"throttle"`` (0-1), with the log's field it came from in ``source``.
    source : str
        ``BAT.Curr``, ``CTUN.ThO`` ...
    slope : ndarray, shape (3,)
        d(b_j − R b_i)/d(regressor), field unit per A (or per full throttle), body frame.
    r_squared : float
        Share of the difference's variance the regression explains (0-1).
    at_full_pct : float
        ``|slope| × max(regressor)`` in % of the field: the interference at the log's highest current.
    follower : tuple of str
        The compass(es) whose own field length follows the regressor (|correlation| ≥ 0.3), possibly empty.
    """

    regressor: str
    source: str
    slope: NDArray[np.float64]
    r_squared: float
    at_full_pct: float
    follower: tuple[str, ...] = ()


@dataclass(frozen=True, eq=False)
class PairRotation:
    """The rotation between two compasses' calibrated fields, eq. (C1)-(C2): ``b_second ≈ rotation @ b_first``.

    Attributes
    ----------
    first, second : str
        The compasses' ids.
    rotation : ndarray, shape (3, 3)
        ``R``, a proper rotation.
    angle_deg, sigma_deg : float
        Its angle and the block-jackknife one-sigma (the largest axis), degrees.
    axis : ndarray, shape (3,)
        Its unit axis (body frame of ``first``).
    n_samples : int
        Common time stamps used.
    information : float
        The smallest eigenvalue of ``(1/N) Σ (I − b̂ b̂ᵀ)`` (0: a rotation axis is undetermined; 2/3 for
        directions spread evenly).
    residual_rms : float
        RMS of ``|b_second − R b_first|``, field unit.
    current : CurrentEffect or None
        The difference against the current or throttle, when the log has one.
    """

    first: str
    second: str
    rotation: NDArray[np.float64]
    angle_deg: float
    sigma_deg: float
    axis: NDArray[np.float64]
    n_samples: int
    information: float
    residual_rms: float
    current: CurrentEffect | None = None

    @property
    def determined(self) -> bool:
        """True when every axis of the rotation is determined (the field directions span more than a line)."""
        return self.information >= 0.02 and math.isfinite(self.sigma_deg)


@dataclass(frozen=True, eq=False)
class Misorientation:
    """A compass whose declared orientation is wrong.

    Attributes
    ----------
    sensor : str
        The compass.
    angle_deg, sigma_deg : float
        How far its declared orientation is off, and the one-sigma.
    correction : ndarray, shape (3, 3)
        ``C``: ``C @ b`` is its field in the true body frame.
    orientation : ndarray, shape (3, 3)
        ``C @ mounting``: the orientation it should declare (``body = orientation @ sensor``).
    nearest : StandardRotation or None
        The firmware's table entry nearest to ``orientation`` (its ``angle_deg`` says how near), None when the
        firmware is unknown.
    evidence : str
        How it was told apart from the others, in words.
    """

    sensor: str
    angle_deg: float
    sigma_deg: float
    correction: NDArray[np.float64]
    orientation: NDArray[np.float64]
    nearest: StandardRotation | None
    evidence: str


@dataclass(frozen=True)
class ArduPilotFigures:
    """ArduPilot's ``Compass::consistent()`` figures for one compass against the primary, over the log.

    Attributes
    ----------
    sensor, primary : str
        The compass compared and the primary.
    xyz_angle_deg, xy_angle_deg : float
        Medians of the 3-D angle and of the horizontal (body x-y) angle, degrees.
    xy_length : float
        Median of ``|b_primary,xy − b_xy|`` in mG (NaN when the unit is not physical).
    fail_share : float
        Share of the stamps (or level headings, see ``basis``) at which one of the three tests fails (0-1).
    failing : tuple of str
        The tests that fail at the median, in words with the limit (``"3-D angle 95° > 90°"``).
    basis : str
        ``"level"`` or ``"log"``, as for :class:`PX4Figures`.
    checked : bool
        False when the compass is not used for yaw (``COMPASS_USEn`` 0): the firmware skips it.
    """

    sensor: str
    primary: str
    xyz_angle_deg: float
    xy_angle_deg: float
    xy_length: float
    fail_share: float
    failing: tuple[str, ...] = ()
    basis: str = "log"
    checked: bool = True


@dataclass(frozen=True)
class PX4Figures:
    """PX4's magnetometer inconsistency angle for one compass against the primary, over the log.

    Attributes
    ----------
    sensor, primary : str
    angle_deg : float
        Median of the angle between the two fields, degrees.
    filtered_max_deg : float
        Maximum of the filtered angle (``0.95 a + 0.05 angle`` per update), what the check compares.
    fail_share : float
        Share of the time stamps at which the filtered angle exceeds ``COM_ARM_MAG_ANG``.
    basis : str
        ``"level"``: over every heading of the vehicle standing level with its motors off (the pre-arm
        situation), from the rotation found and the field's inclination (the filter's steady state);
        ``"log"``: over the log's own time stamps (no attitude to find the inclination with).
    """

    sensor: str
    primary: str
    angle_deg: float
    filtered_max_deg: float
    fail_share: float
    basis: str = "log"


@dataclass(frozen=True, eq=False)
class CompassComparison:
    """What :func:`compare_compasses` finds about a vehicle's compasses.

    Attributes
    ----------
    compasses : tuple of str
        The compasses compared, the primary first.
    unit : str
        The fields' unit.
    pairs : tuple of PairRotation
        Every pair (primary with each other, then the others with each other).
    misoriented : Misorientation or None
        The compass whose declared orientation is wrong, when one is and the data say which.
    ardupilot : tuple of ArduPilotFigures
        ``Compass::consistent()``'s figures for each other compass against the primary.
    px4 : tuple of PX4Figures
        PX4's inconsistency angle for each other compass against the primary.
    priority : tuple of str
        The order to prefer them in (best first).
    findings : tuple of Reason
        What was found, each with a code (``compass_misoriented``, ``compasses_inconsistent``,
        ``compass_follows_current``, ``undetermined``) and what to do.
    notes : tuple of str
        How it was computed (time stamps, frames, the regressor), in words.
    firmware : str or None
        ``"ardupilot"`` or ``"px4"`` when the log says, else None.
    slots, device_ids : tuple
        Each compass's calibration slot and device id (None when unknown), in ``compasses`` order.
    priority_fixed : tuple of str
        The order to prefer them in once the misoriented compass's orientation is set as found (empty when
        there is nothing to fix).
    """

    compasses: tuple[str, ...]
    unit: str
    pairs: tuple[PairRotation, ...]
    misoriented: Misorientation | None
    ardupilot: tuple[ArduPilotFigures, ...]
    px4: tuple[PX4Figures, ...]
    priority: tuple[str, ...]
    findings: tuple[Reason, ...] = ()
    notes: tuple[str, ...] = field(default_factory=tuple)
    firmware: str | None = None
    slots: tuple[int | None, ...] = ()
    device_ids: tuple[int | None, ...] = ()
    priority_fixed: tuple[str, ...] = ()

    @property
    def codes(self) -> tuple[str, ...]:
        return tuple(reason.code for reason in self.findings)


# --------------------------------------------------------------------------------------------------------
# the rotation


def wahba_rotation(first: ArrayLike, second: ArrayLike) -> NDArray[np.float64]:
    """The proper rotation ``R`` minimising ``Σ |second_k − R first_k|²``, eq. (C2).

    Parameters
    ----------
    first, second : array_like, shape (N, 3)
        Paired vectors, rows are samples.

    Raises
    ------
    SampleError
        Shapes differ or are not (N, 3), fewer than 2 rows, or non-finite values.
    """
    a = np.asarray(first, dtype=np.float64)
    b = np.asarray(second, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 3 or a.shape != b.shape:
        raise SampleError(f"wahba_rotation takes two (N, 3) arrays of the same shape, got {a.shape} and {b.shape}")
    if len(a) < 2 or not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise SampleError("wahba_rotation needs at least 2 finite pairs of vectors")
    u, _, vt = np.linalg.svd(a.T @ b)  # H = Σ a bᵀ = U S Vᵀ
    v = vt.T
    d = np.sign(np.linalg.det(v @ u.T)) or 1.0
    rotation: NDArray[np.float64] = v @ np.diag([1.0, 1.0, d]) @ u.T
    return rotation


def _rotation_vector(matrix: NDArray[np.float64]) -> NDArray[np.float64]:
    """log(R) as a rotation vector (axis × angle, radians)."""
    cosine = float(np.clip((np.trace(matrix) - 1.0) / 2.0, -1.0, 1.0))
    angle = math.acos(cosine)
    skew = np.array([matrix[2, 1] - matrix[1, 2], matrix[0, 2] - matrix[2, 0], matrix[1, 0] - matrix[0, 1]])
    if angle < 1e-9:
        return 0.5 * skew
    if math.pi - angle < 1e-6:  # 180°: the axis from the symmetric part
        w, vectors = np.linalg.eigh(0.5 * (matrix + matrix.T))
        return np.asarray(vectors[:, int(np.argmax(w))] * angle, dtype=np.float64)
    return np.asarray(skew * (angle / (2.0 * math.sin(angle))), dtype=np.float64)


def _pair(first: str, second: str, a: NDArray[np.float64], b: NDArray[np.float64]) -> PairRotation:
    rotation = wahba_rotation(a, b)
    vector = _rotation_vector(rotation)
    angle = float(np.degrees(np.linalg.norm(vector)))
    axis = vector / np.linalg.norm(vector) if np.linalg.norm(vector) > 0 else np.array([0.0, 0.0, 1.0])
    # The block jackknife (module docstring): contiguous stretches of the log left out one at a time.
    n = len(a)
    blocks = int(min(20, n // 10))
    sigma = float("nan")
    if blocks >= 5:
        edges = np.linspace(0, n, blocks + 1).astype(int)
        deltas = []
        for lo, hi in itertools.pairwise(edges):
            keep = np.ones(n, dtype=bool)
            keep[lo:hi] = False
            deltas.append(_rotation_vector(rotation.T @ wahba_rotation(a[keep], b[keep])))
        spread = np.asarray(deltas)
        spread -= spread.mean(axis=0)
        covariance = (blocks - 1) / blocks * spread.T @ spread
        sigma = float(np.degrees(math.sqrt(max(float(np.linalg.eigvalsh(covariance)[-1]), 0.0))))
        sigma = math.hypot(sigma, SIGMA_FLOOR_DEG)  # the calibrations' own errors, module docstring
    unit = a / np.maximum(np.linalg.norm(a, axis=1, keepdims=True), 1e-300)
    information = float(np.linalg.eigvalsh(np.eye(3) - unit.T @ unit / n)[0])
    residual = b - a @ rotation.T
    rms = float(np.sqrt(np.mean(np.sum(residual**2, axis=1))))
    return PairRotation(first, second, rotation, angle, sigma, axis, n, information, rms)


# --------------------------------------------------------------------------------------------------------
# common time stamps


def _on_stamps(reference: NDArray[np.float64], other: CompassField) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """``other``'s field linearly interpolated onto ``reference`` stamps, and where that is valid (within its
    span, and no more than 2.5 of its median steps, at least 0.25 s, from its nearest sample)."""
    t = other.time_s
    if len(t) < 2:
        return np.full((len(reference), 3), np.nan), np.zeros(len(reference), dtype=bool)
    order = np.argsort(t, kind="stable")
    t, values = t[order], other.field[order]
    step = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    gap = max(0.25, 2.5 * step)
    index = np.clip(np.searchsorted(t, reference), 1, len(t) - 1)
    nearest = np.minimum(np.abs(reference - t[index - 1]), np.abs(t[index] - reference))
    valid = (reference >= t[0]) & (reference <= t[-1]) & (nearest <= gap)
    out = np.column_stack([np.interp(reference, t, values[:, k]) for k in range(3)])
    return out, valid


def _common(fields: Sequence[CompassField]) -> tuple[NDArray[np.float64], list[NDArray[np.float64]], int]:
    """Every field on the primary's stamps where all are valid; the index of the primary's kept stamps."""
    reference = fields[0].time_s
    valid = np.all(np.isfinite(fields[0].field), axis=1)
    values = [fields[0].field]
    for other in fields[1:]:
        on, ok = _on_stamps(reference, other)
        values.append(on)
        valid &= ok
    keep = np.flatnonzero(valid)
    return reference[keep], [v[keep] for v in values], len(keep)


# --------------------------------------------------------------------------------------------------------
# the firmwares' figures


def _angles_deg(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    cross = np.linalg.norm(np.cross(a, b), axis=1)
    return np.asarray(np.degrees(np.arctan2(cross, np.sum(a * b, axis=1))), dtype=np.float64)


def _ardupilot(
    primary: str,
    sensor: str,
    p: NDArray[np.float64],
    c: NDArray[np.float64],
    to_mg: float | None,
    limits: tuple[float, float, float],
    basis: str,
) -> ArduPilotFigures:
    xyz = _angles_deg(p, c)
    pxy, cxy = p[:, :2], c[:, :2]
    cross = pxy[:, 0] * cxy[:, 1] - pxy[:, 1] * cxy[:, 0]
    xy = np.abs(np.degrees(np.arctan2(cross, np.sum(pxy * cxy, axis=1))))
    length = np.linalg.norm(pxy - cxy, axis=1) * to_mg if to_mg is not None else np.full(len(p), np.nan)
    fails = (xyz > limits[0]) | (xy > limits[1])
    if to_mg is not None:
        fails |= length > limits[2]
    medians = float(np.median(xyz)), float(np.median(xy)), float(np.median(length))
    failing = []
    if medians[0] > limits[0]:
        failing.append(f"3-D angle {medians[0]:.0f}° > {limits[0]:.0f}°")
    if medians[1] > limits[1]:
        failing.append(f"horizontal angle {medians[1]:.0f}° > {limits[1]:.0f}°")
    if math.isfinite(medians[2]) and medians[2] > limits[2]:
        failing.append(f"horizontal difference {medians[2]:.0f} mG > {limits[2]:.0f} mG")
    return ArduPilotFigures(sensor, primary, *medians, float(np.mean(fails)), tuple(failing), basis)


def _px4(
    primary: str, sensor: str, p: NDArray[np.float64], c: NDArray[np.float64], limit_deg: float, basis: str
) -> PX4Figures:
    angle = _angles_deg(p, c)
    if basis == "level":  # a vehicle standing still: the filter's steady state is the angle itself
        filtered = angle
    else:
        filtered = np.empty_like(angle)
        value = 0.0  # VehicleMagnetometer's filter starts at 0
        for k, a in enumerate(angle):
            value = 0.95 * value + 0.05 * float(a)
            filtered[k] = value
    return PX4Figures(
        sensor, primary, float(np.median(angle)), float(np.max(filtered)), float(np.mean(filtered > limit_deg)), basis
    )


def _level_fields(fields: Sequence[CompassField], pairs: Sequence[PairRotation]) -> list[NDArray[np.float64]] | None:
    """Each compass's field on the ground: the vehicle level, its motors off, at every heading (1° apart). The
    primary sees ``Rz(ψ)ᵀ f`` with ``f`` the field in the local level frame (its horizontal and vertical parts
    from the angle between the primary's field and the attitude's down direction); compass k sees
    ``R_0k`` of that (the rotation found, eq. C2). None without an attitude."""
    primary = fields[0]
    if primary.down is None:
        return None
    good = np.all(np.isfinite(primary.down), axis=1) & np.all(np.isfinite(primary.field), axis=1)
    if np.count_nonzero(good) < 20:
        return None
    length = np.linalg.norm(primary.field[good], axis=1)
    down = np.sum(primary.field[good] * primary.down[good], axis=1) / np.maximum(
        np.linalg.norm(primary.down[good], axis=1), 1e-300
    )
    vertical = float(np.median(down))
    horizontal = math.sqrt(max(float(np.median(length)) ** 2 - vertical**2, 0.0))
    heading = np.radians(np.arange(360.0))
    # Rz(ψ)ᵀ (h, 0, v): the body sees north at -ψ
    level = np.column_stack([horizontal * np.cos(heading), -horizontal * np.sin(heading), np.full(360, vertical)])
    out = [level]
    for k in range(1, len(fields)):
        pair = next(p for p in pairs if p.first == primary.sensor and p.second == fields[k].sensor)
        out.append(level @ pair.rotation.T)
    return out


# --------------------------------------------------------------------------------------------------------
# who is wrong


def _inclination_spread_deg(f: CompassField) -> float:
    """Standard deviation of the angle between the compass's field and the down direction (degrees)."""
    if f.down is None:
        return float("nan")
    angles = _angles_deg(f.field, f.down)
    good = np.isfinite(angles)
    return float(np.std(angles[good])) if np.count_nonzero(good) > 10 else float("nan")


def _misoriented(
    fields: Sequence[CompassField], pairs: Sequence[PairRotation]
) -> tuple[Misorientation | None, list[str]]:
    names = [f.sensor for f in fields]
    big = {(p.first, p.second): p for p in pairs if p.angle_deg > max(MISORIENTED_DEG, 3 * (p.sigma_deg or 0))}
    notes: list[str] = []
    if not big:
        return None, notes
    wrong: str | None = None
    evidence = ""
    if len(fields) >= 3:
        for name in names:
            involved = [key for key in big if name in key]
            others_agree = all(name in key for key in big)
            if others_agree and len(involved) == len(names) - 1:
                wrong = name
                evidence = f"its rotation to each of the other {len(names) - 1} compasses is large while they agree"
                break
    if wrong is None and len(big) == 1:
        (first, second), _ = next(iter(big.items()))
        i, j = names.index(first), names.index(second)
        spread_i = _inclination_spread_deg(fields[i])
        spread_j = _inclination_spread_deg(fields[j])
        if math.isfinite(spread_i) and math.isfinite(spread_j):
            low, high = sorted((spread_i, spread_j))
            if high > 2.0 * low and high - low > 1.0:
                wrong = second if spread_j > spread_i else first
                evidence = (
                    f"against the attitude's roll and pitch its field's inclination spreads {high:.1f}° (the other's "
                    f"{low:.1f}°): its axes do not tilt with the vehicle's"
                )
            else:
                notes.append(
                    f"{first} and {second} differ by {big[(first, second)].angle_deg:.0f}°, but the attitude does not "
                    f"say which is wrong (inclination spreads {spread_i:.1f}° and {spread_j:.1f}°)"
                )
        else:
            notes.append(
                f"{first} and {second} differ by {big[(first, second)].angle_deg:.0f}°; with two compasses and no "
                "attitude, which one is wrong cannot be told: log the attitude (ATT) or check both mountings"
            )
    if wrong is None:
        if not notes:
            apart = ", ".join(f"{a} and {b} by {p.angle_deg:.0f}°" for (a, b), p in big.items())
            notes.append(f"the compasses disagree ({apart}) and no single one is the odd one out: check each mounting")
        return None, notes
    index = names.index(wrong)
    reference = next(f for f in names if f != wrong and ((f, wrong) in big or (wrong, f) in big))
    pair = big.get((reference, wrong)) or big[(wrong, reference)]
    # b_wrong ≈ R b_ref (or the converse): C takes the wrong compass's field onto the reference's.
    correction = pair.rotation.T if pair.second == wrong else pair.rotation
    mounting = fields[index].mounting
    declared = mounting if mounting is not None else np.eye(3)
    orientation = correction @ declared
    nearest = None
    if fields[index].firmware in ("ardupilot", "px4"):
        nearest = nearest_rotation(orientation, str(fields[index].firmware))
    return Misorientation(wrong, pair.angle_deg, pair.sigma_deg, correction, orientation, nearest, evidence), notes


# --------------------------------------------------------------------------------------------------------
# the library functions


def compare_fields(
    fields: Sequence[CompassField],
    *,
    regressor: tuple[NDArray[np.float64], NDArray[np.float64], str, str] | None = None,
    ardupilot_limits: tuple[float, float, float] = ARDUPILOT_LIMITS,
    px4_angle_deg: float = PX4_ANGLE_LIMIT_DEG,
) -> CompassComparison:
    """Compare calibrated compass fields of one vehicle (the module docstring gives the model and the checks).

    Parameters
    ----------
    fields : sequence of CompassField
        Two or more, the primary first (ArduPilot's ``COMPASS_PRIO1``; PX4's highest priority).
    regressor : (time_s, values, kind, source) or None
        The battery current (``kind`` ``"current"``, amperes) or the throttle (``"throttle"``, 0-1) on its
        own stamps, with the log field it came from (``"BAT.Curr"``).
    ardupilot_limits : (deg, deg, mG)
        ``Compass::consistent()``'s limits (:data:`ARDUPILOT_LIMITS`; :data:`ARDUPILOT_OLD_LIMITS` for 3.x).
    px4_angle_deg : float
        ``COM_ARM_MAG_ANG``.

    Raises
    ------
    SampleError
        Fewer than two compasses, different units, or fewer than 20 common time stamps.
    """
    if len(fields) < 2:
        raise SampleError("comparing compasses needs at least two")
    units = {f.unit for f in fields}
    if len(units) > 1:
        raise SampleError(
            f"the compasses' fields are in different units ({', '.join(sorted(units))}): convert them first"
        )
    unit = fields[0].unit
    reference, values, n = _common(fields)
    names = tuple(f.sensor for f in fields)
    if n < 20:
        raise SampleError(
            f"the compasses {', '.join(names)} share only {n} time stamps (within 0.25 s of each other's samples): "
            "too few to compare them; log them together"
        )
    pairs = [
        _pair(names[i], names[j], values[i], values[j]) for i in range(len(fields)) for j in range(i + 1, len(fields))
    ]
    findings = ReasonList()
    notes = [f"{n} common time stamps (the primary {names[0]}'s, the others interpolated onto them)"]
    field_size = float(np.median(np.linalg.norm(values[0], axis=1)))

    current_followers: set[str] = set()
    if regressor is not None:
        r_time, r_values, kind, source = regressor
        good = np.isfinite(r_values) & np.isfinite(r_time)
        if np.count_nonzero(good) >= 2:
            x = np.interp(reference, r_time[good], r_values[good], left=np.nan, right=np.nan)
            pairs = [
                _with_current(
                    p, values[names.index(p.first)], values[names.index(p.second)], x, kind, source, field_size
                )
                for p in pairs
            ]
            for p in pairs:
                if p.current is not None:
                    current_followers.update(p.current.follower)
            notes.append(f"the {kind} from {source}, interpolated onto the common stamps")

    # A pair that no rotation brings together (a residual of a quarter of the field) says nothing about mounting:
    # one compass is disturbed or broken, or the two were not sampled at the same instants.
    apart = [p for p in pairs if p.residual_rms > DISAGREE * field_size]
    for p in apart:
        findings.add(
            "compasses_inconsistent",
            f"{p.first} and {p.second} do not see the same field under any rotation (residual "
            f"{100 * p.residual_rms / field_size:.0f} % of the field): one of them is disturbed or faulty, or they "
            f"were not sampled together; compare each with the World Magnetic Model ({option('method', 'vector')})",
        )
    misoriented, said = _misoriented(fields, [p for p in pairs if p not in apart])
    notes += said
    for p in pairs:
        if not p.determined:
            findings.add(
                "undetermined",
                f"the rotation between {p.first} and {p.second} is not determined about every axis (the field's "
                "direction hardly changed): turn the vehicle through several headings and tilts",
            )
    if misoriented is not None:
        m = misoriented
        where = ""
        if m.nearest is not None and m.nearest.angle_deg <= NEAREST_DEG:
            where = f"; it is mounted as {m.nearest.name} ({m.nearest.id}) within {m.nearest.angle_deg:.1f}°"
        elif m.nearest is not None:
            where = (
                f"; no standard rotation is within {NEAREST_DEG:.0f}° (nearest {m.nearest.name}, "
                f"{m.nearest.angle_deg:.0f}° off): remount it square, or declare a custom rotation"
            )
        findings.add(
            "compass_misoriented",
            f"{m.sensor}'s declared orientation is off by {m.angle_deg:.0f}° ± {m.sigma_deg:.1f}° "
            f"({m.evidence}){where}",
            _orientation_remedy(fields[names.index(m.sensor)], m),
        )
    elif said:
        findings.add("compass_misoriented", said[0])

    to_mg = _to_mg(unit)
    level = _level_fields(fields, pairs)
    basis = "log" if level is None else "level"
    checked = values if level is None else level
    if level is None:
        notes.append("the pre-arm figures are over the log's stamps (no attitude to put the vehicle level with)")
    ardupilot = tuple(
        dataclasses.replace(
            _ardupilot(names[0], names[k], checked[0], checked[k], to_mg, ardupilot_limits, basis),
            checked=fields[k].used_for_yaw,
        )
        for k in range(1, len(fields))
    )
    px4 = tuple(
        _px4(names[0], names[k], checked[0], checked[k], px4_angle_deg, basis) for k in range(1, len(fields[:3]))
    )
    firmware = fields[0].firmware
    for figures in ardupilot if firmware in (None, "ardupilot") else ():
        if figures.checked and (figures.failing or figures.fail_share > 0.5):
            findings.add(
                "compasses_inconsistent",
                f"ArduPilot's pre-arm check would fail ('Compasses inconsistent') for {figures.sensor} against "
                f"{figures.primary}: {', '.join(figures.failing) or 'at most headings'} (fails at "
                f"{100 * figures.fail_share:.0f} % of the {_where(basis)})",
            )
    for px in px4 if firmware in (None, "px4") else ():
        if px.fail_share > 0.5:
            findings.add(
                "compasses_inconsistent",
                f"PX4's pre-arm check would fail ('Compass inconsistent by {px.filtered_max_deg:.0f} degrees') for "
                f"{px.sensor} against {px.primary} (COM_ARM_MAG_ANG {px4_angle_deg:.0f}°)",
            )
    for name in sorted(current_followers):
        effect = max(
            (p.current for p in pairs if p.current is not None and name in p.current.follower),
            key=lambda c: c.at_full_pct,
        )
        findings.add(
            "compass_follows_current",
            f"{name}'s field follows the {effect.regressor} ({effect.source}): {effect.at_full_pct:.0f} % of the "
            f"field at the log's highest {effect.regressor}; move it away from the power wires, or fit the motor "
            "compensation",
        )
    priority = _priority(fields, misoriented, current_followers)
    fixable = misoriented is not None and any(r.code == "compass_misoriented" and r.remedy for r in findings)
    priority_fixed = _priority(fields, None, current_followers) if fixable else ()
    return CompassComparison(
        names,
        unit,
        tuple(pairs),
        misoriented,
        ardupilot,
        px4,
        priority,
        tuple(findings),
        tuple(notes),
        fields[0].firmware,
        tuple(f.slot for f in fields),
        tuple(f.device_id for f in fields),
        priority_fixed,
    )


def _where(basis: str) -> str:
    return "headings, level with the motors off" if basis == "level" else "log's time stamps"


def _to_mg(unit: str) -> float | None:
    try:
        return conversion_factor(unit, "mG") if unit and get_unit(unit).is_physical else None
    except MagfitError:
        return None


def _with_current(
    pair: PairRotation,
    a: NDArray[np.float64],
    b: NDArray[np.float64],
    x: NDArray[np.float64],
    kind: str,
    source: str,
    field_size: float,
) -> PairRotation:
    good = np.isfinite(x)
    if np.count_nonzero(good) < 20 or float(np.ptp(x[good])) <= 0:
        return pair
    xs = x[good] - np.mean(x[good])
    difference = (b - a @ pair.rotation.T)[good]
    difference = difference - difference.mean(axis=0)
    slope = xs @ difference / float(xs @ xs)
    explained = float(np.sum((np.outer(xs, slope)) ** 2))
    total = float(np.sum(difference**2))
    r2 = explained / total if total > 0 else 0.0
    at_full = 100.0 * float(np.linalg.norm(slope)) * float(np.nanmax(np.abs(x))) / field_size if field_size > 0 else 0.0
    followers: list[str] = []
    if r2 >= CURRENT_R2:
        # Which one: the difference alone cannot say. Take the effect off each in turn (``b_j − s x`` if j
        # follows, ``b_i + Rᵀ s x`` if i does): the follower's field length becomes steadier, the other's not.
        # The effect's mean is in the calibration's offset when it was fitted on this log, not when it was fitted
        # on a dance with the motors off: both are tried, the steadier kept.
        steadier = {}
        for name, before, effect_on in ((pair.second, b[good], slope), (pair.first, a[good], -pair.rotation.T @ slope)):
            spread = float(np.std(np.linalg.norm(before, axis=1)))
            after = min(
                float(np.std(np.linalg.norm(before - np.outer(regressor, effect_on), axis=1)))
                for regressor in (xs, x[good])
            )
            steadier[name] = after / spread if spread > 0 else 1.0
        for name, ratio in steadier.items():
            other = min(v for k, v in steadier.items() if k != name)
            if ratio < 0.8 and ratio < other:
                followers.append(name)
    effect = CurrentEffect(kind, source, slope, r2, at_full, tuple(followers))
    return PairRotation(
        pair.first,
        pair.second,
        pair.rotation,
        pair.angle_deg,
        pair.sigma_deg,
        pair.axis,
        pair.n_samples,
        pair.information,
        pair.residual_rms,
        effect,
    )


def _orientation_remedy(f: CompassField, m: Misorientation) -> tuple[tuple[str, str], ...]:
    if m.nearest is None or f.slot is None or m.nearest.angle_deg > NEAREST_DEG:
        return ()
    if f.firmware == "ardupilot":
        suffix = "" if f.slot == 0 else str(f.slot + 1)
        return ((f"COMPASS_ORIENT{suffix}", str(m.nearest.id)),)
    if f.firmware == "px4":
        return ((f"CAL_MAG{f.slot}_ROT", str(m.nearest.id)),)
    return ()


def _priority(
    fields: Sequence[CompassField], misoriented: Misorientation | None, followers: set[str]
) -> tuple[str, ...]:
    def rank(index: int) -> tuple[int, int, int, int]:
        f = fields[index]
        return (
            int(misoriented is not None and misoriented.sensor == f.sensor),
            int(f.sensor in followers),
            int(not f.supported),
            index,
        )

    return tuple(fields[k].sensor for k in sorted(range(len(fields)), key=rank))


# --------------------------------------------------------------------------------------------------------
# from a calibrated log


def compass_fields(result: FileCalibration) -> tuple[list[CompassField], list[str]]:
    """Each fitted compass of ``result`` as a :class:`CompassField` (its samples read again, calibrated with the
    symmetric part of its fit, turned into the body frame), in the log's order; and notes in words.

    Raises
    ------
    DataFileError
        The file cannot be read again.
    """
    from .sources import open_source
    from .sources.calibration_messages import read_calibration_messages

    source = open_source(result.path)
    firmware = {"dataflash": "ardupilot", "tlog": "ardupilot", "mavlogdump": "ardupilot", "ulog": "px4"}.get(
        source.kind
    )
    settings = read_calibration_messages(result.path).settings if firmware == "ardupilot" else {}
    fields: list[CompassField] = []
    notes: list[str] = []
    for compass in result.compasses:
        if compass.magnetometer is None:
            continue
        sensor = compass.magnetometer.id
        calibration = compass.calibration
        _, symmetric = polar_decomposition(calibration.matrix)
        time_s: NDArray[np.float64]
        try:
            motion = source.read_motion(sensor)
            time_s, raw, frame, mounting, attitude = (
                motion.time_s,
                motion.samples,
                motion.magnetometer_frame,
                motion.mounting,
                motion.attitude,
            )
        except MagfitError:
            read = source.read(sensor)
            time_s, raw, frame, mounting, attitude = read.time_s, read.samples, "unknown", None, None
        corrected = (raw - calibration.offset) @ symmetric.T
        if frame == "sensor":
            if mounting is None:
                notes.append(f"{sensor}: its mounting is not in the log; compared in its own axes")
            else:
                corrected = corrected @ mounting.T
        elif frame == "unknown" and source.kind == "ulog":
            notes.append(
                f"{sensor}: its frame is unknown (no attitude stream to read it with); compared in its own axes"
            )
        down = None
        if attitude is not None:
            down = np.asarray(attitude[:, 2, :], dtype=np.float64)  # Aᵀ e_z: row 2 of body->NED
        supported = calibration.support is None or calibration.support.verdict == "supported"
        fields.append(
            CompassField(
                sensor,
                np.asarray(time_s, dtype=np.float64),
                np.asarray(corrected, dtype=np.float64),
                calibration.unit or "",
                mounting,
                down,
                compass.magnetometer.slot,
                compass.magnetometer.device_id,
                firmware,
                supported,
                _used_for_yaw(settings, compass.magnetometer.slot),
            )
        )
    return fields, notes


def _used_for_yaw(settings: Mapping[str, float], slot: int | None) -> bool:
    """ArduPilot's ``COMPASS_USE`` / ``USE2`` / ``USE3`` of the compass in ``slot`` (used when not logged)."""
    if slot is None:
        return True
    return bool(settings.get("COMPASS_USE" if slot == 0 else f"COMPASS_USE{slot + 1}", 1))


def _power_regressor(path: Any) -> tuple[NDArray[np.float64], NDArray[np.float64], str, str] | None:
    """The battery current (else the throttle) of a DataFlash log: ``BAT.Curr`` (first battery), older
    ``CURR.Curr``, else ``CTUN.ThO``; None for other formats or when the log has none."""
    from pathlib import Path

    from .sources import log_kind
    from .sources.dataflash import DataFlashLog

    if log_kind(path) != "dataflash":
        return None
    try:
        log = DataFlashLog(Path(path), Path(path).read_bytes())
    except (OSError, DataFileError):
        return None
    sources = (
        ("BAT", "Curr", "current", 1.0),
        ("CURR", "Curr", "current", 0.01),  # an integer field in old logs: centiamperes
        ("CTUN", "ThO", "throttle", 1.0),
        ("CTUN", "ThrOut", "throttle", 0.001),  # old logs: 0 to 1000
    )
    for name, label, kind, integer_unit in sources:
        if not log.has(name):
            continue
        records = log.messages(name)
        labels = records.dtype.names or ()
        if label not in labels or not ({"TimeUS", "TimeMS"} & set(labels)):
            continue
        for instance in ("Inst", "Instance", "I"):
            if instance in labels:
                records = records[records[instance] == np.min(records[instance])]
                break
        time = records["TimeUS"] / 1e6 if "TimeUS" in labels else records["TimeMS"] / 1e3
        values = log.value(records, name, label)
        if _plain_integer(log, name, label):
            values = values * integer_unit
        if np.count_nonzero(np.isfinite(values)) >= 2 and float(np.nanmax(values) - np.nanmin(values)) > 0:
            return np.asarray(time, dtype=np.float64), values, kind, f"{name}.{label}"
    return None


def _plain_integer(log: Any, name: str, label: str) -> bool:
    """The field is stored as a plain integer (no centi- letter): its unit is the old logs' integer unit."""
    type_id = next(k for k, fmt in log.formats.items() if fmt.name == name)
    fmt = log.formats[type_id]
    return fmt.letters[fmt.labels.index(label)] in "bBhHiIqQ"


def compare_compasses(
    result: FileCalibration,
    *,
    ardupilot_limits: tuple[float, float, float] = ARDUPILOT_LIMITS,
    px4_angle_deg: float = PX4_ANGLE_LIMIT_DEG,
) -> CompassComparison:
    """Compare the compasses :func:`magfit.calibrate_file` fitted in one log (see :func:`compare_fields`).

    The samples are read again with their time stamps (and the attitude, when the log has it), each compass
    calibrated with the symmetric part of its fit and turned into the body frame by its declared mounting.
    The regressor is the DataFlash log's battery current (``BAT.Curr``, ``CURR.Curr``) or throttle
    (``CTUN.ThO``) when it has one.

    Raises
    ------
    SampleError
        Fewer than two compasses fitted, or too few common time stamps.
    DataFileError
        The log cannot be read again.
    """
    fields, notes = compass_fields(result)
    if len(fields) < 2:
        raise SampleError(f"{result.path}: {len(fields)} compass fitted; comparing compasses needs at least two")
    comparison = compare_fields(
        fields, regressor=_power_regressor(result.path), ardupilot_limits=ardupilot_limits, px4_angle_deg=px4_angle_deg
    )
    if notes:
        comparison = dataclasses.replace(comparison, notes=comparison.notes + tuple(notes))
    return comparison
