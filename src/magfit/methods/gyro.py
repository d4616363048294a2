"""Gyro-aided calibration: hard and soft iron (and the axes) from the rotation kinematics, without a tumble.

The Earth's field is constant in the world, so in the gyroscope's (body) frame the field ``b`` turns against
the body rate ``ω``: ``db/dt = −ω × b`` (Poisson's equation). The magnetometer reads ``y = G b + V`` (the
paper's eq. (1) with ``G = W Mᵀ``: soft iron W times the rotation Mᵀ from the gyroscope's axes into the
magnetometer's), so with ``H = G⁻¹`` and ``c = H V``::

    H dy/dt = −ω × (H y − c)                                      (1)

linear in (H, c) and homogeneous (the overall scale, and the sign, are free): the equation of MAGYC
(Rodríguez et al., "MAGYC: magnetometer and gyroscope calibration", IEEE J. Oceanic Eng. / arXiv:2410.13827,
2024; the ``magyc`` package), which there takes H symmetric (gyro and magnetometer axes assumed the same),
differentiates the samples (``diff(m)/dt``) and adds the gyro's bias β in ``ω = ω_measured − β``. TWOSTEP
(Alonso & Shuster, J. Astronaut. Sci. 50(4), 2002) uses the field's magnitude only; Huang, Hendeby & Skog
("Joint magnetometer-IMU calibration via maximum a posteriori estimation", arXiv:2505.16662, 2025) estimate
the calibration with the orientation trajectory as unknowns, which stage 2 below does in a reduced form (the
trajectory is the gyro's, integrated, with one unknown start per stretch). Here, in three stages
(measured figures for each choice: docs/methods.md, "gyro"):

1. **Integrated, not differentiated.** (1) integrated over windows ``[a, b]`` of about a second:
   ``H (y_b − y_a) = −∫ ω × (H y − c) dt`` (trapezoids of ``ω yᵀ``, ``y``, ``ω``). A difference of two
   samples (MAGYC's ``diff(m)/dt``) has the magnetometer noise of two samples for one sample's turn; a window
   of L samples has it for L samples' turn. The total least-squares solution (smallest singular vector) gives
   H and c, then Gauss-Newton on the same residual adds the gyro bias.
2. **Maximum likelihood on the samples.** Integrating (1) over whole stretches of ``segment_s`` seconds:
   ``b_k = R_kᵀ b₀`` with ``R_k`` the rotation from the stretch's start integrated from ``ω − β``, so
   ``y_k = G R_kᵀ b₀ + V`` with ``|b₀| = 1`` (G carries the field's magnitude): Levenberg-Marquardt (the
   project's, on the normal equations) on the samples' own residuals over G (general, 9), V, β and each
   stretch's b₀ (2 angles). This uses that the field is one vector for many seconds, which the windows of
   stage 1 forget. Longer stretches add fewer unknowns but let the gyro's noise walk the integrated rotation
   away.
   **With the accelerometer** (``accel=``, optional, in the gyroscope's axes): where it sees gravity alone
   (:func:`magfit.gravity.still_samples`, gated on the rates less stage 1's bias), its down direction
   ``d_k = −a_k/|a_k|`` and the unit field ``b_k`` make the inclination's angle, one for the whole recording::

       (d_k · b_k − sin δ) / cos δ = 0                                  (2)

   (the ``d · (H y − c) = B sin δ`` of the vector methods with ``|b| = 1``), one more residual per sample in
   the same Levenberg-Marquardt, δ one more unknown. It is divided by cos δ because its noise, the
   accelerometer's direction noise across the field, is ``σ cos δ`` in ``d · b``: undivided, a fit lowers it
   by pulling the field towards the vertical. Its weight is the magnetometer rows' noise over its own, each
   the residuals' variance times their correlation in time (five-second batch means), from the general fit
   without it and once more with it. Its sign is free (δ is fitted), so an accelerometer that reports gravity
   instead of the specific force fits alike, with the dip's sign turned. The field's magnitude (TWOSTEP's
   information) needs no rows of its own: ``|b₀| = 1`` holds it in every residual. A rotation about a boat's
   roll axis turns the field about that axis, which the kinematics cannot tell from the axes' own rotation
   about it; gravity turns with the boat too, but the field's angle to it changes with the axes' rotation.
   A tilted accelerometer (its bias over g, or its mounting) leaves (2)'s residual as small as a true one and
   moves the fitted δ and the axes' rotation instead: the covariance takes it as tilted by an unknown
   :data:`ACCEL_BIAS_PRIOR`, and ``inclination_deg=`` (the reference model's) checks δ, dropping the rows when
   they disagree. δ sees only the tilt about the magnetic east-west axis (``∂(d·b)/∂θ = d × b``), so a fit
   the gravity rows pin (the boat) stays weak, saying which tilt is unchecked.
3. **The axis mapping.** A magnetometer is often mounted turned by a right angle (or soldered with its axes
   read in another order) against the gyroscope. A standard mapping P (one of the 24 proper signed
   permutations, :data:`MAPPINGS`) makes ``G = W Pᵀ`` with W symmetric and definite (MAGYC's model in the
   turned frame): 3 unknowns fewer, which a vehicle that hardly tilts needs. The candidates (the mapping
   nearest the general fit's rotation, and the two best of all 24 on the windows of stage 1, whose noise hides
   the differences on a vehicle that hardly tilts) are fitted as in stage 2 and compared with the general G
   by their likelihood ratio (the residual excess in noise variances, the variance from batch means of the
   residuals): the best is kept unless the general G beats it by more than :data:`LIKELIHOOD_RATIO` (then the
   mounting is turned in between, and the rotation and its angle from the nearest mapping are reported). A
   field and its negative turn alike, so (1) cannot tell a mapping P from its mirror −P (the other 24 of the
   48): the magnetometer is taken to be right-handed, and said so. Two candidates that fit alike but turn
   differently (rotations about one axis cannot tell mappings that differ by a turn about it) are a refusal:
   the alignment is not determined.

What the inputs are. (1) fixes how fast the field turns per unit of ``ω dt``, so a gyro in degrees per second
or times in milliseconds scale the turn by 57.3 or 1000, a lag between the clocks shifts it, and a gyro whose
axes are of the other handedness than the magnetometer's (two swapped, or one sign-flipped: ω is a
pseudovector, ``S ω`` for an improper S is ``−(−S) ω``) turns the field backwards, which no G absorbs. Each
reading (:func:`_readings`, :func:`_lagged_readings`) is scored by the windowed residual of stage 1 over the
turning it explains, a correction that no soft iron gives (an axis squeezed :data:`MIN_SINGULAR_RATIO`) not
counted; one far better than the given reading is refused with its own code and remedy, and where the windows
cannot tell (a slow vehicle) and the fit leaves a large residual, stage 2's general fit decides.

What the motion determines (the verdict, in ``details["support"]``): turning about one axis ``a`` only,
``b``'s component along ``a`` stays constant, so ``G a`` and V along the plane's normal are confounded:
the kinematics fix the offset across ``a`` and the distortion of the plane perpendicular to ``a`` (even from
part of a turn: the gyroscope says how far it turned), never the offset along the normal nor the scale
along ``a``. A second rotation axis, even a little bank, makes everything determined in principle; how well
is the covariance of stage 2 (the sandwich of batch sums over the recording, as the diagnostics of the
magnitude-only methods do, for the gyro's noise walks and is correlated in time): an offset one-sigma above
:data:`UNDETERMINED_OFFSET` of the field is a refusal, above :data:`WEAK_OFFSET` a weakness, each with the
heading error it causes. The model fitted again on each half of the recording (:func:`_halves`) must agree
within :data:`HALVES_SIGMAS` of their combined heading one-sigmas, or the disagreement is named.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._optimize import Evaluation, Solution, levenberg_marquardt
from .._validation import check_rows, check_times
from ..calibration import Calibration
from ..errors import CalibrationError, OptionError
from ..findings import Reason, ReasonList, Support
from ..gravity import still_samples
from ..rotations import polar_decomposition
from .registry import FitInput, register

__all__ = ["MAPPINGS", "fit_gyro", "mapping_name"]

#: The magnetometer's delay behind the gyroscope is searched within ± this (seconds).
MAX_LAG_S = 0.25
#: ... and kept when it brings the windowed residual below this share of no delay's.
LAG_GAIN = 0.8
#: Window of the integrated kinematic residual (stage 1), seconds; at least ``_MIN_WINDOW`` samples.
WINDOW_S = 1.0
_MIN_WINDOW = 5
#: At most this many samples enter the maximum-likelihood residuals (a regular stride of the recording);
#: the gyro is integrated at every sample all the same.
MAX_RESIDUAL_SAMPLES = 20_000
#: Rows the candidate mappings are told apart on.
SCREEN_ROWS = 3_000
#: Iterations each candidate mapping gets from the general fit.
SCREEN_ITER = 40
#: At most this many stretches (each adds two unknowns); longer recordings get longer stretches.
MAX_SEGMENTS = 60
#: Combined one-sigmas by which the fits of the two halves of a recording may differ before the verdict names it.
HALVES_SIGMAS = 3.5
#: The samples' residual RMS (fraction of the field) beyond which the fit is weak, and the other readings of
#: the inputs are tried by the fit.
LARGE_RESIDUAL = 0.05
#: Offset one-sigmas (fraction of the field) above which the offset is not determined / weakly determined.
UNDETERMINED_OFFSET = 0.05
WEAK_OFFSET = 0.01
#: Likelihood ratio (residual excess in noise variances) that tells two models of G apart. With independent
#: residuals it would be χ² with 3 degrees of freedom (above 25 with probability 2e-5); the gyro's noise
#: walks, and the right mapping of a one-minute car drive on simulate_vehicle reached 24 against the general
#: matrix with the batch-means variance: 50 keeps it.
LIKELIHOOD_RATIO = 50.0
#: A step of the time stamps longer than this many of their median steps (and than GAP_MIN_S) is a gap: the
#: gyro's turn across it is unknown, so the stages do not integrate across it (a new stretch, no window).
GAP_STEPS = 5.0
GAP_MIN_S = 0.05
#: Fewest samples on which the accelerometer sees gravity alone for the gravity rows to be used.
MIN_GRAVITY_SAMPLES = 50
#: The accelerometer's bias (m/s², over g = 9.81 a tilt of its vertical) and misalignment to the gyroscope taken as
#: unknown in the covariance: a calibrated MEMS accelerometer's residual bias is of this order, and a tilt is
#: invisible in the gravity rows' residual (it moves the fitted dip instead: 0.29° RMS with the accelerometer
#: tilted 5° or not, on accuracy_vehicle's boat, for a dip 4.3° off and 2.8° of heading error).
ACCEL_BIAS_PRIOR = 0.07
#: The reference inclination's own error (the World Magnetic Model's is about 0.3° RMS, more near anomalies),
#: and how many combined one-sigmas a fitted dip may differ from a given one before the accelerometer is
#: taken to disagree (with its calibration or its alignment to the gyroscope) and its rows are dropped.
INCLINATION_MODEL_DEG = 0.3
INCLINATION_SIGMAS = 2.0
#: Turning about the second principal axis below this share of the first: turned about one axis only.
SINGLE_AXIS = 0.02
#: Largest turn (degrees) of the field seen in the samples' frame below which the sensor hardly turned.
MIN_TURN_DEG = 30.0
#: Without the accelerometer, turning about the third principal axis below this share of the first with a field
#: direction spanning less than NARROW_TURN_DEG is weak: a boat rolling on one heading (0.07-0.15, 35-38° on
#: simulate_vehicle) left 1.5° RMS heading error where the one-sigma said 0.8-1.7° (3.0° on one trial that said
#: 0.8°); the cars and flights that met the one-sigma turned 0.09-0.48 about their third axis or spanned 69-107°.
NARROW_THIRD_AXIS = 0.2
NARROW_TURN_DEG = 60.0
#: No soft iron squeezes an axis this much (the smallest singular value of H over its largest): a correction
#: that does only fits samples moving in a plane while it ignores the rates.
MIN_SINGULAR_RATIO = 0.05
#: Another reading of the inputs (degrees per second, milliseconds, the other handedness, a lag beyond
#: MAX_LAG_S) is named when its windowed residual is below this share of the given one's.
READING_GAIN = 0.25
#: ... and when it leaves at most this share of the turning unexplained: on a flight the windows' noise leaves
#: the right reading at 0.03-0.57 (simulate_vehicle, 4 seeds) and its mirror image at 0.07-0.30.
DECISIVE_SHARE = 0.05
#: Noise variances by which the rates negated (the gyro's axes of the other handedness) must fit better than as
#: given to be refused: on simulate_vehicle's boats, flights and cars the wrong sense fits worse by 5 000-1 200 000.
HANDEDNESS_RATIO = 500.0
#: ... when the negated fit's residual sum of squares is within this factor of the samples' white noise.
HANDEDNESS_FLOOR = 1.5
#: The median time step from which time_s may be in milliseconds (a gyro-aided fit at under 5 Hz).
MS_STEP = 0.2
#: Lags beyond MAX_LAG_S are tried, on a grid of WIDE_LAG_STEP_S to MAX_WIDE_LAG_S, when the given reading's
#: windowed residual is over WIDE_LAG_SHARE of the turning it explains (the gyro explains little of it).
WIDE_LAG_STEP_S = 0.25
MAX_WIDE_LAG_S = 10.0
WIDE_LAG_SHARE = 0.1

_EPS = np.zeros((3, 3, 3))
_EPS[0, 1, 2] = _EPS[1, 2, 0] = _EPS[2, 0, 1] = 1.0
_EPS[0, 2, 1] = _EPS[2, 1, 0] = _EPS[1, 0, 2] = -1.0


def _signed_permutations() -> dict[str, NDArray[np.float64]]:
    """The 24 proper signed permutations, named by the gyro axes the magnetometer's x, y, z lie along."""
    table: dict[str, NDArray[np.float64]] = {}
    for order in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            p = np.zeros((3, 3))
            for column, (row, sign) in enumerate(zip(order, signs, strict=True)):
                p[row, column] = sign  # magnetometer axis `column` lies along gyro axis `row`
            if np.linalg.det(p) > 0:
                table[_name(p)] = p
    return table


def _name(p: NDArray[np.float64]) -> str:
    words = []
    for column in range(3):
        row = int(np.argmax(np.abs(p[:, column])))
        words.append(("+" if p[row, column] > 0 else "-") + "xyz"[row])
    return "".join(words)


#: ``mapping`` names: ``"+x-y-z"`` reads "the magnetometer's x along the gyro's +x, its y along −y, its z along
#: −z" (a turn of 180° about x); the matrix M turns magnetometer vectors into the gyro's axes, ``b = M m``.
MAPPINGS: dict[str, NDArray[np.float64]] = _signed_permutations()


def mapping_name(matrix: ArrayLike) -> str:
    """The name in :data:`MAPPINGS` of the signed permutation nearest a rotation (gyro = matrix @ magnetometer)."""
    m = np.asarray(matrix, dtype=np.float64)
    return min(MAPPINGS, key=lambda name: float(np.linalg.norm(MAPPINGS[name] - m)))


# ---------------------------------------------------------------------------------------------- inputs


def _motion(
    gyro: ArrayLike | None, time_s: ArrayLike | None, n: int
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The gyro rates (n, 3) and times (n,), checked; one-line :class:`OptionError` naming what is wrong."""
    if gyro is None:
        raise OptionError(
            "method 'gyro' needs gyro=: the body rates in rad/s, shape (N, 3), one row per magnetometer sample"
        )
    if time_s is None:
        raise OptionError("method 'gyro' needs time_s=: the sample times in seconds, shape (N,)")
    w = check_rows(gyro, "gyro", n, "body rates in rad/s, one row per magnetometer sample")
    return w, check_times(time_s, "time_s", n)


def _own_rate(gyro: ArrayLike | None, gyro_time_s: ArrayLike,
              t: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.bool_], list[str]]:  # fmt: skip
    """A gyroscope logged at its own rate (M, 3) at ``gyro_time_s`` (M,): its mean rate over each magnetometer
    sample's interval (the midpoints to its neighbours), (n, 3), from the running integral of its own samples.

    Read at the magnetometer's stamps instead (interpolated), a fast gyro's vibration aliases into the slow
    rate: the mean over the interval is what turns the field between two samples. The stages downstream then
    take it as one rate per sample, as they take a gyro logged beside the magnetometer.

    Also returns which samples' intervals overlap a gap of the gyro (a step longer than :data:`GAP_STEPS` of
    its median, and than :data:`GAP_MIN_S`), which the caller drops, and a note per gap: across a gap the
    running integral is a straight line, a turn the gyro never saw (a 6 s dropout on a simulated car left
    0.47° of heading error where 0.21° was stated, a 15 s one a refusal for an unrelated cause).
    """
    if gyro is None:
        raise OptionError("gyro_time_s= was given without gyro=: the body rates in rad/s, shape (M, 3), at those times")
    try:
        w = np.asarray(gyro, dtype=np.float64)
        tg = np.asarray(gyro_time_s, dtype=np.float64)
    except (TypeError, ValueError):
        raise OptionError("gyro= and gyro_time_s= must be numeric arrays") from None
    if tg.ndim != 1 or tg.size < 2 or w.shape != (tg.size, 3):
        raise OptionError(
            f"with gyro_time_s= of shape {tg.shape}, gyro= must have shape (M, 3) with M = len(gyro_time_s) ≥ 2, got "
            f"shape {w.shape}; rows are samples, it is never transposed"
        )
    if not (np.all(np.isfinite(w)) and np.all(np.isfinite(tg))):
        raise OptionError("gyro= and gyro_time_s= must be finite (no NaN or inf): drop or fill those rows first")
    steps = np.diff(tg)
    if np.any(steps <= 0):
        at = int(np.argmax(steps <= 0)) + 1
        raise OptionError(
            f"gyro_time_s= must increase strictly; row {at} ({tg[at]:g} s) does not: sort or de-duplicate"
        )
    span, own_span = float(t[-1] - t[0]), float(tg[-1] - tg[0])
    if not 0.1 * span <= own_span <= 10.0 * span:
        # A span far from the magnetometer's is a unit (milliseconds, microseconds), not a longer log: with
        # gyro_time_s= in ms every interval would read the first fraction of a second of the gyro.
        raise OptionError(
            f"gyro_time_s= spans {own_span:g} units where the magnetometer's time_s= spans {span:g} s "
            f"({own_span / max(span, 1e-300):.3g} times as long): one of them is not in seconds (milliseconds? "
            "divide by 1000; microseconds? by 1e6); give both in seconds on one clock, the gyro trimmed to the "
            "magnetometer's span"
        )
    if t[0] < tg[0] or t[-1] > tg[-1]:
        raise OptionError(
            f"gyro_time_s= spans {tg[0]:g}-{tg[-1]:g} s, the magnetometer's time_s= {t[0]:g}-{t[-1]:g} s: the gyro "
            "must cover every sample (same clock, same unit); trim the samples to the gyro's span"
        )
    turned = np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * (w[:-1] + w[1:]) * steps[:, None], axis=0)])
    edges = np.concatenate([[t[0] - 0.5 * (t[1] - t[0])], 0.5 * (t[:-1] + t[1:]), [t[-1] + 0.5 * (t[-1] - t[-2])]])
    edges = np.clip(edges, tg[0], tg[-1])
    at_edges = np.column_stack([np.interp(edges, tg, turned[:, axis]) for axis in range(3)])
    rates = np.asarray(np.diff(at_edges, axis=0) / np.diff(edges)[:, None], dtype=np.float64)
    gaps = np.nonzero(steps > max(GAP_STEPS * float(np.median(steps)), GAP_MIN_S))[0]
    dropped = np.zeros(t.size, dtype=bool)
    notes = []
    for gap in gaps:
        # the samples whose interval [edge_k, edge_k+1] overlaps the gap (tg[gap], tg[gap + 1])
        overlap = (edges[1:] > tg[gap]) & (edges[:-1] < tg[gap + 1])
        dropped |= overlap
        if np.any(overlap):
            notes.append(
                f"the gyro has no sample from {tg[gap]:g} s to {tg[gap + 1]:g} s ({steps[gap]:.3g} s, "
                f"{steps[gap] / float(np.median(steps)):.0f} of its steps): the {int(overlap.sum())} magnetometer "
                "samples there were dropped and the integration restarts after it"
            )
    return rates, dropped, notes


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


# -------------------------------------------------------------------------------- stage 1: windows


@dataclass(frozen=True)
class _Windows:
    """Per window ``[a, b]``: ``dy = y_b − y_a``, ``M = ∫ ω yᵀ dt``, ``Sy = ∫ y dt``, ``Sw = ∫ ω dt``, ``T``."""

    dy: NDArray[np.float64]
    M: NDArray[np.float64]
    Sy: NDArray[np.float64]
    Sw: NDArray[np.float64]
    T: NDArray[np.float64]


def _gaps(t: NDArray[np.float64]) -> NDArray[np.bool_]:
    """(n − 1,) True at the steps of ``t`` that are gaps (:data:`GAP_STEPS`): nothing is integrated across them."""
    steps = np.diff(t)
    return np.asarray(steps > max(GAP_STEPS * float(np.median(steps)), GAP_MIN_S), dtype=bool)


def _windows(y: NDArray[np.float64], w: NDArray[np.float64], t: NDArray[np.float64], length: int) -> _Windows:
    dt = np.diff(t)
    # Trapezoids of each interval, summed cumulatively: every window is a difference of two sums.
    pieces_m = (
        0.5 * (np.einsum("ki,kj->kij", w[:-1], y[:-1]) + np.einsum("ki,kj->kij", w[1:], y[1:])) * dt[:, None, None]
    )
    pieces_y = 0.5 * (y[:-1] + y[1:]) * dt[:, None]
    pieces_w = 0.5 * (w[:-1] + w[1:]) * dt[:, None]
    cm = np.concatenate([np.zeros((1, 3, 3)), np.cumsum(pieces_m, axis=0)])
    cy = np.concatenate([np.zeros((1, 3)), np.cumsum(pieces_y, axis=0)])
    cw = np.concatenate([np.zeros((1, 3)), np.cumsum(pieces_w, axis=0)])
    starts = np.arange(0, len(y) - length, length)
    ends = starts + length
    crossed = np.concatenate([[0], np.cumsum(_gaps(t))])  # gaps among the steps before each sample
    whole = crossed[ends] == crossed[starts]  # a window across a gap would integrate a turn nobody measured
    starts, ends = starts[whole], ends[whole]
    return _Windows(y[ends] - y[starts], cm[ends] - cm[starts], cy[ends] - cy[starts], cw[ends] - cw[starts],
                    t[ends] - t[starts])  # fmt: skip


def _design(win: _Windows, beta: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rows of the integrated (1) in θ = (H row by row, c): ``H dy + ∫ (ω−β) × (H y) − ∫(ω−β) × c``, (3m, 12)."""
    m = win.T.size
    moment = win.M - beta[None, :, None] * win.Sy[:, None, :]  # ∫ (ω − β) yᵀ
    turn = win.Sw - beta * win.T[:, None]  # ∫ (ω − β)
    design = np.zeros((m, 3, 12))
    for i in range(3):
        design[:, i, 3 * i : 3 * i + 3] = win.dy
    design[:, :, :9] += np.einsum("ijk,mjl->mikl", _EPS, moment).reshape(m, 3, 9)  # (ω × H y)_i = ε_ijk ω_j H_kl y_l
    design[:, :, 9:] = -np.einsum("ijk,mj->mik", _EPS, turn)
    return design.reshape(3 * m, 12)


def _symmetric(left: NDArray[np.float64], right: NDArray[np.float64]) -> NDArray[np.float64]:
    """(9, 6): ``left @ S @ right`` row by row for S symmetric, over an orthonormal basis of S (unit |S|_F)."""
    basis = np.zeros((9, 6))
    pairs = [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)]
    for column, (a, b) in enumerate(pairs):
        s = np.zeros((3, 3))
        s[a, b] = s[b, a] = 1.0 if a == b else math.sqrt(0.5)
        basis[:, column] = (left @ s @ right).ravel()
    return basis


def _constrained(
    design: NDArray[np.float64], basis: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """H = basis @ h with |h| = 1 and the best c minimising the windowed residual: (H, c, residual²).

    c is eliminated (the Schur complement of the normal equations) and h is the eigenvector of the smallest
    eigenvalue of what is left, so the residuals of different models of H (general, or ``P S`` for each
    mapping) are on one scale (|H|_F = 1). Normal equations through einsum, not an SVD or QR of the tall
    design: LAPACK's threads on a shared machine made those 80 % of a long recording's fit.
    """
    d_h = np.einsum("rj,jk->rk", design[:, :9], basis)
    d_c = design[:, 9:]
    n_hh = np.einsum("rj,rk->jk", d_h, d_h)
    n_hc = np.einsum("rj,rk->jk", d_h, d_c)
    n_cc = np.einsum("rj,rk->jk", d_c, d_c)
    eliminate = np.linalg.solve(n_cc, n_hc.T)  # c = −N_cc⁻¹ N_chᵀ h
    values, vectors = np.linalg.eigh(n_hh - n_hc @ eliminate)
    h = vectors[:, 0]
    return (basis @ h).reshape(3, 3), -eliminate @ h, float(max(values[0], 0.0))


def _windowed_bias(win: _Windows, iterations: int = 20) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Gauss-Newton on the windowed residual over θ = (H, c) (on its unit sphere: the scale is free) and β,
    from the bias-free total least-squares solution."""
    h, c, _ = _constrained(_design(win, np.zeros(3)), np.eye(9))
    theta = np.concatenate([h.ravel(), c])
    theta /= np.linalg.norm(theta)
    beta = np.zeros(3)
    m = win.T.size
    for _ in range(iterations):
        h, c = theta[:9].reshape(3, 3), theta[9:]
        residual = np.einsum("rj,j->r", _design(win, beta), theta)
        # H ∫y − T c: the residual is linear in β through −β × u
        u = np.einsum("ij,mj->mi", h, win.Sy) - win.T[:, None] * c
        jac_theta = _design(win, beta)
        jac_beta = np.einsum("ijk,mj->mik", _EPS, u).reshape(3 * m, 3)
        q, _ = np.linalg.qr(np.column_stack([theta, np.eye(12)]))
        tangent = q[:, 1:12]
        jac = np.column_stack([np.einsum("rj,jk->rk", jac_theta, tangent), jac_beta])
        normal = np.einsum("rp,rq->pq", jac, jac)
        step, *_ = np.linalg.lstsq(normal, -np.einsum("rp,r->p", jac, residual), rcond=None)
        theta = theta + tangent @ step[:11]
        theta = theta / np.linalg.norm(theta)
        beta = beta + step[11:]
        if np.linalg.norm(step) < 1e-10:
            break
    return theta, beta


# ----------------------------------------------------------------------- stage 2: maximum likelihood


def _quaternion_product(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    w1, x1, y1, z1 = a.T
    w2, x2, y2, z2 = b.T
    return np.column_stack([
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
    ])  # fmt: skip


def _turns(w: NDArray[np.float64], t: NDArray[np.float64], beta: NDArray[np.float64],
           segment: NDArray[np.int64]) -> NDArray[np.float64]:  # fmt: skip
    """R_k (n, 3, 3): the body's rotation from its stretch's first sample to sample k (``v_start = R_k v_k``).

    Each step turns by the mean rate of its two samples (``dR/dt = R [ω]×``); the steps are chained by a
    prefix product (Hillis-Steele: log₂ n vectorised quaternion products, not a loop over samples).
    """
    rates = 0.5 * (w[:-1] + w[1:]) - beta
    phi = rates * np.diff(t)[:, None]
    angle = np.linalg.norm(phi, axis=1)
    sinc = np.where(angle > 1e-12, np.sin(0.5 * angle) / np.maximum(angle, 1e-300), 0.5)
    n = t.size
    q = np.zeros((n, 4))
    q[:, 0] = 1.0
    q[1:] = np.column_stack([np.cos(0.5 * angle), phi * sinc[:, None]])
    q[1:][segment[1:] != segment[:-1]] = (1.0, 0.0, 0.0, 0.0)  # a stretch starts from itself
    shift = 1
    while shift < n:
        index = np.nonzero(segment[shift:] == segment[:-shift])[0] + shift
        chained = q.copy()
        chained[index] = _quaternion_product(q[index - shift], q[index])
        q = chained
        shift *= 2
    s, x, y, z = q.T
    return np.stack([
        np.column_stack([1 - 2 * (y * y + z * z), 2 * (x * y - s * z), 2 * (x * z + s * y)]),
        np.column_stack([2 * (x * y + s * z), 1 - 2 * (x * x + z * z), 2 * (y * z - s * x)]),
        np.column_stack([2 * (x * z - s * y), 2 * (y * z + s * x), 1 - 2 * (x * x + y * y)]),
    ], axis=1)  # fmt: skip


def _unit(angles: NDArray[np.float64]) -> NDArray[np.float64]:
    elevation, azimuth = angles[:, 0], angles[:, 1]
    return np.column_stack(
        [np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)]
    )


def _cos(inclination: float) -> float:
    """cos δ, held above 0.1 (a dip beyond 84°, near a magnetic pole, leaves the heading ill-defined anyway)."""
    return max(math.cos(inclination), 0.1)


def _gravity_angle(down: NDArray[np.float64], b: NDArray[np.float64], inclination: float) -> NDArray[np.float64]:
    """(2) as an angle: ``(d · b − sin δ) / cos δ``, to first order the field's dip error in radians.

    Divided by cos δ so that its noise (the accelerometer's direction noise across the field, ``σ cos δ`` in
    ``d · b``) does not depend on δ: undivided, a fit lowers it by pulling the field towards the vertical
    (measured on simulated boats: the dip came out 70-79° for 64°, the heading error 4x worse).
    """
    return np.asarray((np.einsum("ki,ki->k", down, b) - math.sin(inclination)) / _cos(inclination), dtype=np.float64)


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


@dataclass(frozen=True)
class _Trajectory:
    """What the maximum-likelihood residual needs: the recording, its stretches, the rows it is read at and
    the model of G (``G.ravel() = basis @ q``: general, or ``W Pᵀ`` with W symmetric for a standard mapping).

    The parameters are ``p = (q, V, β, [δ,] the stretches' (elevation, azimuth) of b₀)``, the inclination δ
    only with gravity rows. Each row has three magnetometer residuals ``G b_k + V − y_k`` and, with gravity, a
    fourth ``weight · (d_k · b_k − sin δ) / cos δ`` (zero where the accelerometer does not see gravity alone).
    """

    y: NDArray[np.float64]
    w: NDArray[np.float64]
    t: NDArray[np.float64]
    segment: NDArray[np.int64]
    rows: NDArray[np.int64]
    count: int
    basis: NDArray[np.float64]
    gravity: _Gravity | None = None

    @property
    def k(self) -> int:
        return int(self.basis.shape[1])

    @property
    def head(self) -> int:
        """Parameters every row may depend on: q, V, β (and δ with gravity); the stretches' angles follow."""
        return self.k + 6 + (self.gravity is not None)

    @property
    def components(self) -> int:
        """Residuals per row: the magnetometer's three, and the gravity row's."""
        return 3 + (self.gravity is not None)

    def n_residuals(self) -> int:
        """Residuals that carry data (the gravity rows of moving samples are zeros)."""
        gravity = 0 if self.gravity is None else int(np.sum(self.gravity.still[self.rows]))
        return 3 * self.rows.size + gravity

    def distortion(self, p: NDArray[np.float64]) -> NDArray[np.float64]:
        """G (3, 3) from the parameters."""
        return np.asarray(self.basis @ p[: self.k], dtype=np.float64).reshape(3, 3)

    def field(self, p: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """b_k = R_kᵀ b₀ at ``rows``, the (rows, 3, 3) rotations, and ∂b_k/∂β (rows, 3, 3).

        ``R_k = D_0 … D_{k−1}`` with ``D_j = exp([(ω̄_j − β) dt_j]×)``, so to first order in each step
        ``δR_k = −[C_k δβ]× R_k`` with ``C_k = Σ_{j<k} dt_j R_{j+1}`` (a running sum over the stretch), and
        ``∂b_k/∂β = −R_kᵀ [b₀]× C_k``.
        """
        k = self.k
        turns = _turns(self.w, self.t, p[k + 3 : k + 6], self.segment)
        steps = np.zeros_like(turns)
        steps[1:] = turns[1:] * np.diff(self.t)[:, None, None]
        steps[1:][self.segment[1:] != self.segment[:-1]] = 0.0
        running = np.cumsum(steps, axis=0)
        first = np.searchsorted(self.segment, self.segment)  # each sample's stretch start (segments ascend)
        running = (running - running[first])[self.rows]
        turns = turns[self.rows]
        start = _unit(p[self.head :].reshape(self.count, 2))[self.segment[self.rows]]
        skew = np.einsum("ijk,mj->mik", _EPS, start)  # [b₀]×: (b₀ × v)_i = ε_ijk b₀_j v_k
        d_beta = -np.einsum("kji,kjl,klm->kim", turns, skew, running)
        return np.einsum("kji,kj->ki", turns, start), turns, d_beta

    def _gravity_rows(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """d_k (rows, 3) and each row's weight (rows,): 0 where the accelerometer is not still."""
        assert self.gravity is not None
        down = self.gravity.down[self.rows]
        return down, self.gravity.weight * self.gravity.still[self.rows].astype(np.float64)

    def _residual_of(self, p: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
        magnetometer = np.einsum("ij,kj->ki", self.distortion(p), b) + p[self.k : self.k + 3] - self.y[self.rows]
        if self.gravity is None:
            return magnetometer
        down, weight = self._gravity_rows()
        return np.column_stack([magnetometer, weight * _gravity_angle(down, b, p[self.k + 6])])

    def residual(self, p: NDArray[np.float64]) -> NDArray[np.float64]:
        """All residuals, (rows · components,): row by row, the magnetometer's three then the gravity row."""
        return self._residual_of(p, self.field(p)[0]).ravel()

    def magnetometer_residual(self, p: NDArray[np.float64]) -> NDArray[np.float64]:
        """The samples' own residuals ``G b_k + V − y_k``, (rows, 3), in the samples' unit."""
        return self.residual(p).reshape(-1, self.components)[:, :3]

    def blocks(self, p: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """The residual (rows, C), its Jacobian in (q, V, β[, s]) (rows, C, head), and in the row's own
        stretch's two angles (rows, C, 2): every other angle column of a row is zero. C = :attr:`components`."""
        k = self.k
        g = self.distortion(p)
        b, turns, d_beta = self.field(p)
        rows = self.rows.size
        residual = self._residual_of(p, b)
        dense = np.zeros((rows, self.components, self.head))
        for i in range(3):
            # ∂(G b)_i / ∂G_ij = b_j, through the basis
            dense[:, i, :k] = np.einsum("kj,jq->kq", b, self.basis[3 * i : 3 * i + 3])
        dense[:, :3, k : k + 3] = np.eye(3)
        dense[:, :3, k + 3 : k + 6] = np.einsum("ij,kjm->kim", g, d_beta)
        angles = p[self.head :].reshape(self.count, 2)[self.segment[self.rows]]
        elevation, azimuth = angles[:, 0], angles[:, 1]
        up, across = np.sin(elevation), np.cos(elevation)
        d_start = np.stack([
            np.column_stack([-up * np.cos(azimuth), -up * np.sin(azimuth), across]),
            np.column_stack([-across * np.sin(azimuth), across * np.cos(azimuth), np.zeros(rows)]),
        ], axis=2)  # fmt: skip
        angular = np.zeros((rows, self.components, 2))
        angular[:, :3] = np.einsum("ij,kmj,kmn->kin", g, turns, d_start)  # G R_kᵀ ∂b₀
        if self.gravity is not None:
            down, weight = self._gravity_rows()
            inclination = p[k + 6]
            across = weight / _cos(inclination)
            dense[:, 3, k + 3 : k + 6] = across[:, None] * np.einsum("ki,kim->km", down, d_beta)
            # ∂/∂δ of (x − sin δ) / cos δ = −1 + tan δ · (x − sin δ) / cos δ
            dense[:, 3, k + 6] = weight * (-1.0 + math.tan(inclination) * _gravity_angle(down, b, inclination))
            angular[:, 3] = across[:, None] * np.einsum("ki,kmi,kmn->kn", down, turns, d_start)
        return residual, dense, angular

    def jacobian(self, p: NDArray[np.float64]) -> NDArray[np.float64]:
        """The whole Jacobian (C·rows, p.size), zeros included (the covariance's sandwich needs it row by row)."""
        _, dense, angular = self.blocks(p)
        rows = self.rows.size
        jac = np.zeros((rows, self.components, p.size))
        jac[:, :, : self.head] = dense
        columns = self.head + 2 * self.segment[self.rows]
        for shift in range(2):
            jac[np.arange(rows), :, columns + shift] = angular[:, :, shift]
        return jac.reshape(self.components * rows, p.size)

    def normal_equations(self, p: NDArray[np.float64]) -> Evaluation:
        """½ Σ r², JᵀJ and Jᵀr from the blocks: the angle columns of a stretch only meet its own rows.

        einsum, not BLAS: a threaded gemm on a tall, narrow Jacobian is 10-100x slower when cores are shared.
        """
        residual, dense, angular = self.blocks(p)
        head = self.head
        starts = np.searchsorted(self.segment[self.rows], np.arange(self.count))  # rows ascend in stretch
        normal = np.zeros((p.size, p.size))
        normal[:head, :head] = np.einsum("kip,kiq->pq", dense, dense)
        cross = np.add.reduceat(np.einsum("kip,kin->kpn", dense, angular), starts, axis=0)  # (count, head, 2)
        own = np.add.reduceat(np.einsum("kim,kin->kmn", angular, angular), starts, axis=0)  # (count, 2, 2)
        for s in range(self.count):
            columns = slice(head + 2 * s, head + 2 * s + 2)
            normal[:head, columns] = cross[s]
            normal[columns, :head] = cross[s].T
            normal[columns, columns] = own[s]
        gradient = np.concatenate([
            np.einsum("kip,ki->p", dense, residual),
            np.add.reduceat(np.einsum("kin,ki->kn", angular, residual), starts, axis=0).ravel(),
        ])  # fmt: skip
        return Evaluation(0.5 * float(np.sum(residual**2)), normal, gradient)


def _trajectory(y: NDArray[np.float64], w: NDArray[np.float64], t: NDArray[np.float64], segment_s: float,
                basis: NDArray[np.float64], max_rows: int = MAX_RESIDUAL_SAMPLES,
                gravity: _Gravity | None = None) -> _Trajectory:  # fmt: skip
    span = float(t[-1] - t[0])
    length = max(segment_s, span / MAX_SEGMENTS)
    segment = np.minimum(((t - t[0]) // length).astype(np.int64), max(int(span // length) - 1, 0))
    # a gap in the time stamps starts a new stretch too: the gyro's turn across it is unknown
    segment = np.concatenate([[0], np.cumsum((np.diff(segment) != 0) | _gaps(t))]).astype(np.int64)
    stride = max(1, math.ceil(y.shape[0] / max_rows))
    rows = np.arange(0, y.shape[0], stride)
    return _Trajectory(y, w, t, segment, rows, int(segment.max()) + 1, basis, gravity)


def _start(traj: _Trajectory, g: NDArray[np.float64], offset: NDArray[np.float64],
           beta: NDArray[np.float64]) -> NDArray[np.float64]:  # fmt: skip
    """Parameters for ``traj`` from G (any scale: |b₀| = 1 rescales it), V and β; b₀ (and s) read off the
    samples."""
    h = np.linalg.inv(g)
    field = np.einsum("ij,kj->ki", h, traj.y - offset)
    radius = float(np.median(np.linalg.norm(field, axis=1)))
    first = np.array([field[np.argmax(traj.segment == s)] for s in range(traj.count)])
    first /= np.linalg.norm(first, axis=1)[:, None]
    angles = np.column_stack([np.arcsin(np.clip(first[:, 2], -1, 1)), np.arctan2(first[:, 1], first[:, 0])])
    q, *_ = np.linalg.lstsq(traj.basis, (g * radius).ravel(), rcond=None)
    head = [q, offset, beta]
    if traj.gravity is not None:
        still = traj.gravity.still
        unit = field[still] / np.linalg.norm(field[still], axis=1)[:, None]
        dots = np.einsum("ki,ki->k", traj.gravity.down[still], unit)
        head.append(np.array([math.asin(float(np.clip(np.median(dots), -0.99, 0.99)))]))
    return np.concatenate([*head, angles.ravel()])


def _maximum_likelihood(traj: _Trajectory, start: NDArray[np.float64], iterations: int = 60) -> Solution:
    """Levenberg-Marquardt on the samples' residuals (the project's solver: normal equations, k ≤ 135)."""

    def evaluate(p: NDArray[np.float64], warm: Any) -> Evaluation:
        return traj.normal_equations(p)

    return levenberg_marquardt(evaluate, start, n_residuals=traj.n_residuals(), max_iterations=iterations)


def _covariance(traj: _Trajectory, p: NDArray[np.float64]) -> NDArray[np.float64]:
    """The sandwich covariance of p: batch sums of the score over 20-40 contiguous stretches of the recording."""
    rows, components = traj.rows.size, traj.components
    jac = traj.jacobian(p).reshape(rows, components, p.size)
    residual = traj.residual(p).reshape(rows, components)
    information = np.einsum("kip,kiq->pq", jac, jac)
    inverse = np.linalg.pinv(information)
    dof = max(traj.n_residuals() - p.size, 1)
    independent = inverse * float(np.sum(residual**2)) / dof
    score = np.einsum("kip,ki->kp", jac, residual)
    batches = max(2, min(40, rows // 50))
    sums = np.array([s.sum(axis=0) for s in np.array_split(score, batches)])
    middle = sums.T @ sums * batches / (batches - 1)
    sandwich = inverse @ middle @ inverse
    # Never below the independent-noise covariance (a few batches can understate it by chance).
    covariance = _larger(sandwich, independent)
    if traj.gravity is not None:
        # An accelerometer tilted by θ (its bias over g, or its mounting against the gyro) moves every d_k by
        # θ × d_k, which the fit absorbs: p moves by −(JᵀJ)⁻¹ Jᵀ ∂r/∂θ, added for θ of ACCEL_BIAS_PRIOR / g.
        b = traj.field(p)[0]
        down, weight = traj._gravity_rows()
        tilt = np.zeros((rows, components, 3))
        tilt[:, 3] = (weight / _cos(float(p[traj.k + 6])))[:, None] * np.cross(down, b)  # ∂(d·b)/∂θ = d × b
        shift = -inverse @ np.einsum("kip,kiq->pq", jac, tilt)
        covariance = covariance + (ACCEL_BIAS_PRIOR / 9.81) ** 2 * shift @ shift.T
    return covariance


def _larger(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """``b`` plus the positive part of ``a − b``: the larger of two covariances."""
    values, vectors = np.linalg.eigh(a - b)
    return b + (vectors * np.clip(values, 0, None)) @ vectors.T


# ------------------------------------------------------------------------------- stage 3: the axis mapping


def _windowed_ranking(design: NDArray[np.float64]) -> list[str]:
    """The 24 standard mappings ``H = P S`` ranked by the windowed residual (best first): cheap, and a
    shortlist only, for on a vehicle that hardly tilts the windows' noise hides the differences."""
    residual = {name: _constrained(design, _symmetric(p, np.eye(3)))[2] for name, p in MAPPINGS.items()}
    return sorted(residual, key=residual.__getitem__)


@dataclass(frozen=True)
class _Model:
    """One model of G fitted by maximum likelihood: ``"general"`` or a :data:`MAPPINGS` name."""

    name: str
    traj: _Trajectory
    solution: Solution

    @property
    def rss(self) -> float:
        return 2.0 * self.solution.evaluation.cost


def _fit_model(y: NDArray[np.float64], w: NDArray[np.float64], t: NDArray[np.float64], segment_s: float,
               name: str, g: NDArray[np.float64], offset: NDArray[np.float64], beta: NDArray[np.float64],
               max_rows: int = MAX_RESIDUAL_SAMPLES, iterations: int = 60,
               gravity: _Gravity | None = None) -> _Model:  # fmt: skip
    basis = np.eye(9) if name == "general" else _symmetric(np.eye(3), MAPPINGS[name].T)  # G = W Pᵀ = (P S)⁻¹
    traj = _trajectory(y, w, t, segment_s, basis, max_rows, gravity)
    return _Model(name, traj, _maximum_likelihood(traj, _start(traj, g, offset, beta), iterations))


def _effective_variance(residual: NDArray[np.float64], times: NDArray[np.float64], unknowns: int) -> float:
    """The variance per component of ``residual`` (rows, m), times the correlation excess of the residuals in
    time.

    Neighbouring residuals share the gyro's integrated noise (a random walk over each stretch) and the
    magnetometer's filtering: the variance of means over five-second blocks of rows, times the block length,
    over the plain variance (at least 1).
    """
    variance = float(np.sum(residual**2)) / max(residual.size - unknowns, 1)
    step = float(np.median(np.diff(times))) if times.size > 1 else 1.0
    block = max(1, round(5.0 / step))
    blocks = residual.shape[0] // block
    if blocks < 10:
        return variance
    means = residual[: blocks * block].reshape(blocks, block, residual.shape[1]).mean(axis=1)
    excess = block * float(np.mean(means**2)) / max(float(np.mean(residual**2)), 1e-300)
    return variance * max(1.0, excess)


def _noise_variance(model: _Model) -> float:
    """The magnetometer residuals' variance per component, times their correlation excess in time."""
    traj = model.traj
    residual = traj.magnetometer_residual(model.solution.params)
    return _effective_variance(residual, traj.t[traj.rows], model.solution.params.size)


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


def _choose(
    y: NDArray[np.float64],
    w: NDArray[np.float64],
    t: NDArray[np.float64],
    win: _Windows,
    mapping: str,
    segment_s: float,
    gravity: _Gravity | None = None,
) -> tuple[_Model, dict[str, float], tuple[str, str, float] | None]:
    """The model kept: the general G, or ``W Pᵀ`` for the standard mapping the samples prefer (module docstring).

    Returns the model, each candidate's residual excess over the general fit in noise variances (a
    likelihood ratio: χ² with 3 degrees of freedom when the mapping is right), and the two mappings that
    are not told apart, with their separation, when searching found two.
    """
    _, beta = _windowed_bias(win)
    design = _design(win, beta)
    h, c, _ = _constrained(design, np.eye(9))
    # Every model is first fitted on a stride of the recording (SCREEN_ROWS rows): the general one from the
    # windows, each candidate mapping from the general one (the right mapping starts at its optimum, a wrong
    # one stays far off), so that the likelihood ratios compare like with like; the one kept is refitted on
    # every row (up to MAX_RESIDUAL_SAMPLES) from there.
    offset = np.asarray(np.linalg.lstsq(h, c, rcond=None)[0], dtype=np.float64)
    inverse = np.asarray(np.linalg.inv(h), dtype=np.float64)
    general = _fit_model(y, w, t, segment_s, "general", inverse, offset, beta, SCREEN_ROWS)
    _check_handedness(y, w, t, win, segment_s, general)
    if gravity is not None:
        # The weight from the kinematic fit's residuals, then once more from the fit with the gravity rows:
        # the first residuals carry the fit's own error in the direction the gravity rows pin.
        for _ in range(2):
            gravity = _weighted(general, gravity)
            general = _fit_model(y, w, t, segment_s, "general", *_parts(general), SCREEN_ROWS, gravity=gravity)
    chosen, excess, ambiguous = general, {}, None
    if mapping != "general":
        if mapping in MAPPINGS:
            names = [mapping]
        else:
            g = general.traj.distortion(general.solution.params)
            rotation, _ = polar_decomposition(np.linalg.inv(g) * np.sign(np.linalg.det(g)))
            names = list(dict.fromkeys([mapping_name(rotation), *_windowed_ranking(design)[:2]]))
        start = _parts(general)
        fitted = [_fit_model(y, w, t, segment_s, name, *start, SCREEN_ROWS, SCREEN_ITER, gravity) for name in names]
        # W = G P must be definite (a soft iron; negative for a mirrored sensor): an indefinite W is P times a
        # half turn about W's eigenvectors, another mounting that this label does not stand for.
        screened = sorted((m for m in fitted if _definite(m)), key=lambda m: m.rss)
        if mapping in MAPPINGS and not screened:
            raise CalibrationError(
                f"the samples do not support the gyro calibration with mapping={mapping!r}: with the magnetometer's "
                "axes turned that way no soft iron fits (the fitted one is not positive definite: the mounting is "
                "another); leave mapping='search' to find it",
                codes=("gyro",), remedy=(("mapping", "search"),),
            )
        if not screened:
            return _fit_model(y, w, t, segment_s, "general", *_parts(general), gravity=gravity), {}, None
        variance = _noise_variance(general)
        excess = {m.name: (m.rss - general.rss) / variance for m in screened}
        best = screened[0]
        if mapping in MAPPINGS or excess[best.name] <= LIKELIHOOD_RATIO:  # else: turned in between
            chosen = best
            # Two labels can fit one matrix (P S with S indefinite is another mapping's P' S'): a rival is a
            # candidate whose fitted rotation differs from the best one's, not merely its label.
            rivals = [m for m in screened[1:] if _angle_deg(_rotation(m), _rotation(best)) > 10.0]
            if mapping == "search" and rivals:
                separation = excess[rivals[0].name] - excess[best.name]
                if separation < LIKELIHOOD_RATIO:
                    ambiguous = (mapping_name(_rotation(best)), mapping_name(_rotation(rivals[0])), separation)
    return _fit_model(y, w, t, segment_s, chosen.name, *_parts(chosen), gravity=gravity), excess, ambiguous


def _check_handedness(y: NDArray[np.float64], w: NDArray[np.float64], t: NDArray[np.float64], win: _Windows,
                      segment_s: float, general: _Model) -> None:  # fmt: skip
    """The general fit of stage 2 with the rates negated (the gyro's axes of the other handedness, module
    docstring): far better by :data:`HANDEDNESS_RATIO` noise variances is refused. Where the windows cannot
    tell (a boat's roll, a flight), this fit can: on simulate_vehicle the wrong sense fits worse by thousands."""
    negated = _Windows(win.dy, -win.M, win.Sy, -win.Sw, win.T)
    try:
        _, beta = _windowed_bias(negated)
        h, c, _ = _constrained(_design(negated, beta), np.eye(9))
        offset = np.asarray(np.linalg.lstsq(h, c, rcond=None)[0], dtype=np.float64)
        start = np.asarray(np.linalg.inv(h), dtype=np.float64)
        mirrored = _fit_model(y, -w, t, segment_s, "general", start, offset, beta, SCREEN_ROWS)
    except np.linalg.LinAlgError:
        return
    g = mirrored.traj.distortion(mirrored.solution.params)
    singular = np.linalg.svd(g, compute_uv=False)
    if not singular[-1] >= MIN_SINGULAR_RATIO * singular[0]:
        return
    ratio = (general.rss - mirrored.rss) / max(_noise_variance(mirrored), 1e-300)
    # ... and the negated fit must follow the samples to about their own white noise (third differences): a
    # given fit that is poor for another reason (a flight that hardly turned, a lag) is not beaten by a
    # negated one that is merely less poor (a flight with its gyro 0.1 s late: 2.0x the noise, given 12x).
    third = np.diff(y, n=3, axis=0)
    floor = 3 * mirrored.traj.rows.size * float(np.median(np.sum(third**2, axis=1))) / (20.0 * 2.3660)
    if ratio > HANDEDNESS_RATIO and mirrored.rss < HANDEDNESS_FLOOR * floor:
        reading = next(r for r in _readings(w, t) if r.code == "gyro_axes")
        _refuse_reading(reading, f"with the rates negated, the samples follow the turning {ratio:.0f} noise "
                                 "variances better")  # fmt: skip


def _definite(model: _Model) -> bool:
    """True when the symmetric W of a mapping's model ``G = W Pᵀ`` has eigenvalues of one sign."""
    w = model.traj.distortion(model.solution.params) @ MAPPINGS[model.name]
    values = np.linalg.eigvalsh(0.5 * (w + w.T))
    return bool(values.min() > 0 or values.max() < 0)


def _rotation(model: _Model) -> NDArray[np.float64]:
    """The rotation part of a fitted model's correction, taken proper (module docstring: the sign is free)."""
    g = model.traj.distortion(model.solution.params)
    h = np.linalg.inv(g)
    return polar_decomposition(h * np.sign(np.linalg.det(h)))[0]


def _angle_deg(a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(a.T @ b) - 1.0) / 2.0, -1.0, 1.0))))


def _parts(model: _Model) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """G, V and β of a fitted model."""
    params, k = model.solution.params, model.traj.k
    return model.traj.distortion(params), params[k : k + 3], params[k + 3 : k + 6]


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


# ------------------------------------------------------------------------------------------ the verdict


def _turn_axes(win: _Windows, beta: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """How much the recording turned about each principal axis and those axes (columns), largest first.

    The scatter of the windows' turns ``∫ (ω − β) dt`` (a second each: the gyro's noise averages out of
    them, where the scatter of the rates themselves would count it as turning); the square roots of its
    eigenvalues, in degrees, in proportion to the turning about each axis.
    """
    turns = win.Sw - beta * win.T[:, None]
    values, vectors = np.linalg.eigh(turns.T @ turns)
    order = values.argsort()[::-1]
    return np.degrees(np.sqrt(np.clip(values[order], 0, None))), vectors[:, order]


def _axis_words(vector: NDArray[np.float64], frame: str) -> str:
    """``"the gyro's z axis"`` when within 15° of one, else the direction's components."""
    unit = vector / np.linalg.norm(vector)
    axis = int(np.argmax(np.abs(unit)))
    if abs(unit[axis]) > math.cos(math.radians(15)):
        return f"the {frame}'s {'xyz'[axis]} axis"
    return f"the {frame} direction ({unit[0]:+.2f}, {unit[1]:+.2f}, {unit[2]:+.2f})"


def _heading_sigma(g: NDArray[np.float64], offset: NDArray[np.float64], covariance: NDArray[np.float64],
                   traj: _Trajectory) -> float:  # fmt: skip
    """RMS over eight level headings of the heading one-sigma (degrees) that the covariance of (q, V) gives.

    The field dips 60° (the diagnostics' default inclination); the heading of the corrected body field,
    ``atan2(−b_y, b_x)``, is differentiated numerically in the parameters of G and V.
    """
    k = traj.k
    if np.linalg.det(g) < 0:
        # (−G, V, antipodal b₀) fits alike; the level fields below are G's own, so take the proper sign with
        # its covariance (q's correlation with V turns): unturned, a stretch restarted after a gyro gap that
        # converged to −G stated 0.62° for 0.08°.
        g = -g
        turn = np.concatenate([-np.ones(k), np.ones(covariance.shape[0] - k)])
        covariance = covariance * np.outer(turn, turn)
    dip = math.radians(60.0)
    headings = np.radians(np.arange(0, 360, 45))
    body = np.column_stack(
        [math.cos(dip) * np.cos(headings), -math.cos(dip) * np.sin(headings), np.full(8, math.sin(dip))]
    )
    raw = body @ g.T + offset
    q, *_ = np.linalg.lstsq(traj.basis, g.ravel(), rcond=None)
    base = np.concatenate([q, offset])

    def heading(params: NDArray[np.float64]) -> NDArray[np.float64]:
        corrected = (raw - params[k:]) @ np.linalg.inv((traj.basis @ params[:k]).reshape(3, 3)).T
        return np.asarray(np.arctan2(-corrected[:, 1], corrected[:, 0]), dtype=np.float64)

    reference = heading(base)
    gradient = np.zeros((8, k + 3))
    scale = np.concatenate([np.full(k, float(np.abs(g).max())), np.full(3, float(np.abs(g).max()))]) * 1e-6
    for i in range(k + 3):
        moved = base.copy()
        moved[i] += scale[i]
        change = np.angle(np.exp(1j * (heading(moved) - reference)))
        gradient[:, i] = change / scale[i]
    block = covariance[: k + 3, : k + 3]
    variances = np.einsum("hi,ij,hj->h", gradient, block, gradient)
    return float(np.degrees(np.sqrt(np.mean(np.clip(variances, 0, None)))))


_ADVICE = (
    "record while the vehicle turns about at least two of its axes (turns with banks, a few rolls and pitches, "
    "or a tumble), with the gyroscope logged at the magnetometer's rate on the same clock"
)


def _support(
    ambiguous: tuple[str, str, float] | None,
    offset_sigma: NDArray[np.float64],
    offset_axes: NDArray[np.float64],
    heading_sigma: float,
    residual_rms: float,
    span_deg: float,
    lag: float = 0.0,
    turns_deg: NDArray[np.float64] | None = None,
    gravity: bool = False,
    accel_unused: str | None = None,
    inclination_checked: bool = False,
    disagreement: str | None = None,
    lag_searched: bool = True,
) -> Support:
    """The verdict on what the rotations determine (module docstring)."""
    refusals = ReasonList()
    weak = ReasonList()
    if span_deg < MIN_TURN_DEG:
        refusals.add("single_axis",
            f"the sensor hardly turned: the field's direction in its frame spans {span_deg:.0f}°, where the "
            f"kinematics need turns of {MIN_TURN_DEG:.0f}° or more"
        )
    if ambiguous is not None:
        first, second, separation = ambiguous
        refusals.add("gyro",
            f"the rotations do not tell the axis mapping {first} from {second} (the samples fit both within "
            f"{separation:.1f} noise variances, where {LIKELIHOOD_RATIO:.0f} would tell them apart): the "
            "magnetometer's alignment to the gyroscope is not determined; turn about a second axis, or give "
            "mapping= if the mounting is known"
        )
    worst = int(np.argmax(offset_sigma))
    where = _axis_words(offset_axes[:, worst], "magnetometer")
    if offset_sigma[worst] > UNDETERMINED_OFFSET:
        refusals.add("undetermined",
            f"the samples do not determine the offset along {where} (one-sigma {100 * offset_sigma[worst]:.0f} % of "
            "the field): that number would be noise"
        )
    elif offset_sigma[worst] > WEAK_OFFSET:
        weak.add("weakly_determined",
            f"the offset along {where} is weakly determined (one-sigma {100 * offset_sigma[worst]:.1f} % of the "
            f"field); the heading uncertainty that follows is ±{heading_sigma:.2g}°"
        )
    elif heading_sigma > 1.0:
        weak.add(
            "weakly_determined",
            f"the heading uncertainty the fit leaves is ±{heading_sigma:.2g}° (one-sigma, level, 60° dip)",
        )
    planar = turns_deg is not None and turns_deg[2] < NARROW_THIRD_AXIS * turns_deg[0]
    narrow = planar and MIN_TURN_DEG <= span_deg < NARROW_TURN_DEG
    if not gravity and narrow:
        fix = (
            "give accel= (the accelerometer, in the gyroscope's axes) to pin it with gravity" if accel_unused is None
            else f"accel= was given but {accel_unused}"
        )  # fmt: skip
        weak.add("accelerometer",
            f"the field's direction spans only {span_deg:.0f}° in the magnetometer's frame, turning mostly about one "
            "axis (as a boat rolling on one heading): the axes' rotation about that axis rests on the little turning "
            f"about the others and its one-sigma understates it; {fix}"
        )
    elif gravity and narrow:
        # The dip sees the accelerometer's tilt about the magnetic east-west axis only (∂(d·b)/∂θ = d × b): a
        # tilt about north-south is absorbed by the axes' rotation, which is what the gravity rows pin here (a
        # 0.3 m/s² bias on one of 8 simulated boats: the dip 0.3° off, 3.3° of heading error for ±0.9°).
        checked = (
            "its tilt about the field's horizontal direction is not checked by the dip (its tilt across it agreed "
            "with inclination_deg=)" if inclination_checked
            else "its bias and alignment to the gyroscope are not checked; give inclination_deg= (the World "
            "Magnetic Model's) to check them across the field's horizontal direction"
        )  # fmt: skip
        weak.add("accelerometer",
            f"the field's direction spans only {span_deg:.0f}° in the magnetometer's frame, turning mostly about one "
            "axis: the axes' rotation about it rests on the accelerometer's gravity, taken true within "
            f"{ACCEL_BIAS_PRIOR:g} m/s² in the one-sigma (a 1° tilt or a 0.3 m/s² bias left up to 1.8° or 3.4° of "
            f"heading error on simulated boats); {checked}"
        )
    if disagreement is not None and not narrow:  # the calibration may be what is off: the user must know
        weak.add("inclination", disagreement)
    if residual_rms > LARGE_RESIDUAL:
        weak.add("large_residual",
            f"the samples leave {100 * residual_rms:.1f} % of the field (RMS) off the turning field the gyroscope "
            "predicts: the gyro and magnetometer are not on one clock, or the field changed while recording (motors, "
            "a magnet); expect heading errors of a few degrees"
        )
    if lag_searched and abs(lag) >= MAX_LAG_S - 1e-9:
        weak.add("lag_at_edge",
            f"the magnetometer and the gyroscope fit best {lag:+.2f} s apart, the end of the range searched: their "
            "time stamps are not on one clock; check them (or give lag_s=)"
        )
    return Support.judged(refusals, weak, _ADVICE)


def _level_headings(g: NDArray[np.float64], raw: NDArray[np.float64], offset: NDArray[np.float64]) -> NDArray[Any]:
    """The headings (radians) of ``raw`` corrected by (G, V), as :func:`_heading_sigma` reads them."""
    corrected = (raw - offset) @ np.linalg.inv(g).T
    return np.asarray(np.arctan2(-corrected[:, 1], corrected[:, 0]), dtype=np.float64)


def _halves(model: _Model, segment_s: float) -> tuple[float, float] | None:
    """(RMS heading difference, combined one-sigma), degrees, of the model fitted again on each half of the
    recording (the same mapping, from the whole fit), at the eight level headings of :func:`_heading_sigma`;
    None when a half is too short to fit."""
    traj, p = model.traj, model.solution.params
    g, offset = traj.distortion(p), p[traj.k : traj.k + 3]
    g = g * np.sign(np.linalg.det(g))  # (−G, V, antipodal b₀) fits alike: the level fields below are G's own
    dip = math.radians(60.0)
    headings_deg = np.radians(np.arange(0, 360, 45))
    body = np.column_stack(
        [math.cos(dip) * np.cos(headings_deg), -math.cos(dip) * np.sin(headings_deg), np.full(8, math.sin(dip))]
    )
    raw = body @ g.T + offset
    n = traj.t.size
    headings, variances = [], []
    for half in (slice(0, n // 2), slice(n // 2, n)):
        t = traj.t[half]
        if float(t[-1] - t[0]) < 20 * WINDOW_S:
            return None
        gravity = traj.gravity
        if gravity is not None:  # a half whose accelerometer never sees gravity alone is fitted without it
            gravity = replace(gravity, down=gravity.down[half], still=gravity.still[half])
            gravity = gravity if int(np.sum(gravity.still)) >= MIN_GRAVITY_SAMPLES else None
        try:
            fitted = _fit_model(traj.y[half], traj.w[half], t, segment_s, model.name, *_parts(model), gravity=gravity)
            g_half = fitted.traj.distortion(fitted.solution.params)
            offset_half = fitted.solution.params[fitted.traj.k : fitted.traj.k + 3]
            covariance = _covariance(fitted.traj, fitted.solution.params)
        except np.linalg.LinAlgError:
            return None
        g_half = g_half * np.sign(np.linalg.det(g_half))
        headings.append(_level_headings(g_half, raw, offset_half))
        variances.append(_heading_sigma(g_half, offset_half, covariance, fitted.traj) ** 2)
    difference = np.angle(np.exp(1j * (headings[0] - headings[1])))
    return math.degrees(float(np.sqrt(np.mean(difference**2)))), math.sqrt(sum(variances))


# --------------------------------------------------------------- the delay, the gyro's unit, the method


def _delayed(w: NDArray[np.float64], t: NDArray[np.float64], lag: float) -> NDArray[np.float64]:
    """The gyro read ``lag`` seconds earlier at each sample time (linear interpolation; the ends held)."""
    if lag == 0.0:
        return w
    return np.column_stack([np.interp(t - lag, t, w[:, axis]) for axis in range(3)])


def _search_lag(y: NDArray[np.float64], w: NDArray[np.float64], t: NDArray[np.float64], length: int) -> float:
    """The magnetometer's delay behind the gyroscope (s) that minimises the windowed residual of stage 1.

    A magnetometer read at a lower rate and held (Betaflight's logs repeat a fifth of their samples), or
    filtered, reports the field late: measured on the Betaflight recording, the windowed residual falls 3.4
    times from no delay to 5 ms and the maximum-likelihood residual from 4.8 % to 4.2 % of the field. A grid
    of ±MAX_LAG_S in steps of the sample interval (at least 5 ms), the bias of no delay held, then the
    vertex of the parabola through the best point and its neighbours. Kept only when it lowers the windowed
    residual by more than LAG_GAIN: on a slowly turning vehicle the minimum is shallow and biased (simulated
    cars and flights without any delay found -12 to -17 ms, 1-2 % lower residuals, and the heading error
    then doubled), while a real delay shows plainly (the Betaflight recording: 3.4 times lower).
    """
    step = max(float(np.median(np.diff(t))), 0.005)
    grid = np.arange(-MAX_LAG_S, MAX_LAG_S + step / 2, step)
    _, beta = _windowed_bias(_windows(y, w, t, length))
    residual = np.array([_constrained(_design(_windows(y, _delayed(w, t, lag), t, length), beta), np.eye(9))[2]
                         for lag in grid])  # fmt: skip
    best = int(np.argmin(residual))
    if residual[best] > LAG_GAIN * residual[int(np.argmin(np.abs(grid)))]:
        return 0.0
    if best in (0, grid.size - 1):
        return float(grid[best])
    # Refined with the bias fitted at each candidate: held at no delay's, it pulls the minimum towards zero
    # (simulate_vehicle's tumble, the gyro 0.1 s late: -0.084 s found, 0.99° of heading error at a stated
    # 0.17°; refined, -0.100 s and 0.04°).
    from scipy.optimize import minimize_scalar  # not needed to import magfit

    def refitted(lag: float) -> float:
        win = _windows(y, _delayed(w, t, lag), t, length)
        return _constrained(_design(win, _windowed_bias(win)[1]), np.eye(9))[2]

    low, high = float(grid[best] - 2 * step), float(grid[best] + 2 * step)
    result = minimize_scalar(refitted, bounds=(low, high), method="bounded", options={"xatol": 1e-3 * step})
    return float(result.x)


@dataclass(frozen=True)
class _Reading:
    """One reading of the inputs (module docstring, "What the inputs are"): the rates and times as the
    kinematics would take them, and what the user must change to give them so (code, words, remedy)."""

    code: str
    w: NDArray[np.float64]
    t: NDArray[np.float64]
    words: str = ""
    remedy: tuple[tuple[str, str], ...] = ()


def _readings(w: NDArray[np.float64], t: NDArray[np.float64]) -> list[_Reading]:
    """The readings compared with the one given: degrees per second, the gyro's axes of the other handedness,
    and time in milliseconds or microseconds where the steps are long enough to be."""
    step = float(np.median(np.diff(t)))
    found = [
        _Reading("gyro_unit", w * (math.pi / 180.0), t,
                 "gyro= looks like degrees per second: give it in rad/s (numpy.radians(gyro))",
                 (("gyro", "numpy.radians(gyro)"),)),
        _Reading("gyro_axes", -w, t,
                 "gyro= turns the field the wrong way round: the gyro's axes are of the other handedness than the "
                 "magnetometer's (two of them swapped, or one with its sign flipped); give them in the order and "
                 "signs of the sensor's datasheet or the firmware's board rotation, right-handed",
                 (("gyro", "the rates about right-handed axes"),)),
    ]  # fmt: skip
    for factor, unit, minimum in ((1e-3, "milliseconds", MS_STEP), (1e-6, "microseconds", 1e3 * MS_STEP)):
        if step >= minimum:
            divisor = f"{1 / factor:.0f}"
            found.append(_Reading(
                "time_unit", w, t * factor,
                f"time_s= looks like {unit}: its steps are a median {step:.3g} units apart, and the gyro explains "
                f"the samples' turning only with them divided by {divisor}; give it in seconds (time_s / {divisor})",
                (("time_s", f"time_s / {divisor}"),)))  # fmt: skip
    return found


def _lagged_readings(w: NDArray[np.float64], t: NDArray[np.float64]) -> list[_Reading]:
    """The gyro read earlier or later than :data:`MAX_LAG_S` allows: a grid of :data:`WIDE_LAG_STEP_S` out to
    :data:`MAX_WIDE_LAG_S` (at most a quarter of the recording)."""
    reach = min(MAX_WIDE_LAG_S, 0.25 * float(t[-1] - t[0]))
    grid = np.arange(WIDE_LAG_STEP_S, reach + 1e-9, WIDE_LAG_STEP_S)
    return [
        _Reading("lag_at_edge", _delayed(w, t, lag), t,
                 f"the magnetometer and the gyroscope fit only {lag:+.2f} s apart, beyond the ±{MAX_LAG_S:g} s "
                 f"searched: their time stamps are not on one clock; align them, or give lag_s={lag:.2f}",
                 (("lag_s", f"{lag:.2f}"),))
        for lag in (float(sign * value) for value in grid[grid > MAX_LAG_S] for sign in (1.0, -1.0))
    ]  # fmt: skip


def _windowed_share(y: NDArray[np.float64], reading: _Reading, bias: bool = True) -> float:
    """The windowed residual of stage 1 (the bias fitted, unless ``bias`` is False) over the turning it explains,
    ``|r|² / Σ |H dy|²``; inf when only a correction that no soft iron gives fits (an axis squeezed
    :data:`MIN_SINGULAR_RATIO`: samples that move in a plane are also fitted by a rank-one H that ignores the
    rates)."""
    length = max(_MIN_WINDOW, round(WINDOW_S / float(np.median(np.diff(reading.t)))))
    win = _windows(y, reading.w, reading.t, length)
    if win.T.size < 20:
        return math.inf
    try:
        beta = _windowed_bias(win)[1] if bias else np.zeros(3)
        h, _, rss = _constrained(_design(win, beta), np.eye(9))
    except np.linalg.LinAlgError:
        return math.inf
    singular = np.linalg.svd(h, compute_uv=False)
    turning = float(np.sum((win.dy @ h.T) ** 2))
    if not (singular[-1] >= MIN_SINGULAR_RATIO * singular[0] and turning > 0):
        return math.inf
    return rss / turning


def _refuse_reading(best: _Reading, how: str) -> None:
    """The one-line error for a reading of the inputs that the samples prefer to the one given."""
    error = CalibrationError if best.code == "lag_at_edge" else OptionError
    raise error(f"{best.words}; {how}", codes=(best.code,), remedy=best.remedy)


def _check_readings(y: NDArray[np.float64], w: NDArray[np.float64], t: NDArray[np.float64],
                    lag_given: bool = False) -> list[_Reading]:  # fmt: skip
    """Refuses inputs that the kinematics read far better another way (stage 1's windows): in degrees per
    second, in milliseconds, of the other handedness, or beyond the lag searched. Returns the candidates the
    windows left open, best first (what :func:`_check_readings_by_fit` tries when the fit is poor)."""
    given = _windowed_share(y, _Reading("given", w, t))
    scored = [(_windowed_share(y, reading), reading) for reading in _readings(w, t)]
    if not lag_given and not given < WIDE_LAG_SHARE and min(share for share, _ in scored) >= DECISIVE_SHARE:
        # The gyro explains little of the turning, read any other way too: is it late or early? The lags are
        # ranked without the bias (a tenth of the cost), the best one scored with it.
        lagged = _lagged_readings(w, t)
        shares = [_windowed_share(y, reading, bias=False) for reading in lagged]
        if lagged and min(shares) < math.inf:
            best_lag = lagged[int(np.argmin(shares))]
            scored.append((_windowed_share(y, best_lag), best_lag))
    scored.sort(key=lambda pair: pair[0])
    share, best = scored[0]
    if share < min(READING_GAIN * given, DECISIVE_SHARE):
        told = (
            "only read so do the kinematics fit with a soft iron" if math.isinf(given)
            else f"read so, the kinematics fit {given / max(share, 1e-300):.0f} times better"
        )  # fmt: skip
        _refuse_reading(best, told)
    return [reading for _, reading in scored]


def _check_readings_by_fit(y: NDArray[np.float64], t: NDArray[np.float64], readings: list[_Reading],
                           segment_s: float, residual_rms: float) -> None:  # fmt: skip
    """The general fit of stage 2 on each open reading (:func:`_check_readings`): one that leaves a third of
    the given reading's residual or less is named (a slow vehicle's windows cannot tell the unit)."""
    for reading in readings:
        length = max(_MIN_WINDOW, round(WINDOW_S / float(np.median(np.diff(reading.t)))))
        try:
            win = _windows(y, reading.w, reading.t, length)
            _, beta = _windowed_bias(win)
            h, c, _ = _constrained(_design(win, beta), np.eye(9))
            offset = np.asarray(np.linalg.lstsq(h, c, rcond=None)[0], dtype=np.float64)
            start = np.asarray(np.linalg.inv(h), dtype=np.float64)
            model = _fit_model(y, reading.w, reading.t, segment_s, "general", start, offset, beta, SCREEN_ROWS)
        except np.linalg.LinAlgError:
            continue
        g = model.traj.distortion(model.solution.params)
        singular = np.linalg.svd(g, compute_uv=False)
        if not singular[-1] >= MIN_SINGULAR_RATIO * singular[0]:
            continue
        strength = abs(float(np.linalg.det(g))) ** (1.0 / 3.0)
        rms = math.sqrt(model.rss / model.traj.rows.size) / strength
        if rms < residual_rms / 3.0:
            _refuse_reading(reading, f"the samples leave {100 * residual_rms:.0f} % of the field off the turning the "
                                     f"gyro predicts as given, {100 * rms:.1f} % read so")  # fmt: skip


def _check_gyro(w: NDArray[np.float64], y: NDArray[np.float64]) -> None:
    """A gyro that never changes while the samples do: not a gyroscope's reading (a stream not logged)."""
    if np.ptp(w, axis=0).max() > 0 or np.ptp(y, axis=0).max() == 0:
        return
    what = "(0, 0, 0)" if not np.any(w) else f"the same rate {tuple(float(v) for v in w[0])}"
    raise CalibrationError(
        f"the samples do not support the gyro calibration: gyro= reads {what} on every row while the samples "
        "change: a gyroscope not logged or not running; give its body rates in rad/s",
        codes=("gyro",),
    )


@register(
    "gyro",
    min_samples=50,
    data="samples",
    summary="gyro-aided: hard iron, soft iron and the axes from the rotation kinematics (no tumble needed)",
    needs=("gyro", "time_s"),
)
def fit_gyro(
    data: FitInput,
    *,
    gyro: ArrayLike | None = None,
    time_s: ArrayLike | None = None,
    mapping: str = "search",
    segment_s: float = 10.0,
    lag_s: float | str = "search",
    accel: ArrayLike | None = None,
    gyro_time_s: ArrayLike | None = None,
    inclination_deg: float | None = None,
) -> Calibration:
    """Hard iron, soft iron and the magnetometer's axes in the gyroscope's, from the rotation kinematics.

    Parameters
    ----------
    data : FitInput
        The magnetometer samples (N, 3), any unit, in recording order.
    gyro : array_like, shape (N, 3)
        Body rates in rad/s, one row per sample (same clock), or (M, 3) at ``gyro_time_s``. Its constant bias
        is estimated.
    time_s : array_like, shape (N,)
        Sample times in seconds, strictly increasing.
    mapping : str
        ``"search"`` (the standard axis mappings tried, the general matrix kept when none fits),
        ``"general"`` (any rotation, no search), or a name of :data:`MAPPINGS` (``"+x+y+z"``: the axes
        coincide, MAGYC's model).
    segment_s : float
        Length of the stretches over which the gyro is integrated (module docstring, stage 2).
    lag_s : float or "search"
        The magnetometer's delay behind the gyroscope, seconds: searched within ±0.25 s on the windowed
        residual by default (``details["lag_s"]``), or given.
    gyro_time_s : array_like, shape (M,), optional
        The gyroscope's own times (seconds, the magnetometer's clock) when it is logged at its own rate: then
        ``gyro`` is (M, 3) and is averaged over each magnetometer sample's interval, not interpolated.
    accel : array_like, shape (N, 3), optional
        The accelerometer's specific force in the gyroscope's axes, any unit, one row per sample, on the
        gyroscope's clock: adds the gravity rows (2) where it sees gravity alone (module docstring).
    inclination_deg : float, optional
        The local field's inclination (the World Magnetic Model's), degrees: with ``accel``, a fitted dip that
        differs from it by more than :data:`INCLINATION_SIGMAS` times its one-sigma and
        :data:`INCLINATION_MODEL_DEG` combined (signs aside: the accelerometer's sign is free) means the
        accelerometer's calibration or alignment is off: its rows are dropped, the fit is the one without
        them, and the verdict is at most weak, saying so. Without it that is not checked (a weakness where
        the gravity rows carry the fit).

    Returns
    -------
    Calibration
        ``frame="vehicle"``: ``matrix`` turns into the gyroscope's axes (a proper rotation: a mirrored
        magnetometer cannot be told from a proper one by the kinematics), ``|det| = 1``; ``field_strength``
        the fitted magnitude. ``details``: the gyro bias and its one-sigma (rad/s), the mapping and the
        likelihood ratios that chose it, the rotation and its angle from the nearest standard mapping, the
        offset's one-sigma, ``sensor_matrix`` (the symmetric, magnitude-only root), and the verdict
        (``support``). With ``accel``: ``gravity`` (``used``, ``still_samples``, ``dropped``, ``notes``, and
        when used ``weight``, ``residual_rms_deg``, ``inclination_deg`` with ``inclination_sigma_deg``; when
        not, the ``reason``; ``inclination_given_deg`` when checked). With ``gyro_time_s``: ``gyro_gaps``, a
        line per gap of the gyro whose samples were dropped (``n_samples`` counts those kept).

    Raises
    ------
    OptionError
        gyro= or time_s= missing, of the wrong shape, not finite, not increasing, or in degrees per second;
        gyro_time_s= likewise, not covering the samples, or spanning more than 10 times or less than a tenth
        of time_s= (another unit); accel= of the wrong shape, not finite, or a row of zeros; inclination_deg
        beyond ±90.
    CalibrationError
        Too short a recording, or one that turned about one axis only (named).
    """
    try:
        return _fit_gyro(data, gyro=gyro, time_s=time_s, mapping=mapping, segment_s=segment_s, lag_s=lag_s,
                         accel=accel, gyro_time_s=gyro_time_s, inclination_deg=inclination_deg)  # fmt: skip
    except np.linalg.LinAlgError:  # degenerate inputs the checks above let through (rates of 1e-300 rad/s)
        raise CalibrationError(
            "the samples do not support the gyro calibration: with these rates and samples the kinematics are "
            f"singular (no turning the gyro and the samples agree on); {_ADVICE}",
            codes=("gyro",),
        ) from None


def _fit_gyro(data: FitInput, *, gyro: ArrayLike | None, time_s: ArrayLike | None, mapping: str, segment_s: float,
              lag_s: float | str, accel: ArrayLike | None, gyro_time_s: ArrayLike | None,
              inclination_deg: float | None) -> Calibration:  # fmt: skip
    """:func:`fit_gyro`'s work (its docstring)."""
    y = data.require_samples("gyro")
    n = y.shape[0]
    gap_notes: list[str] = []
    kept = np.ones(n, dtype=bool)
    if gyro_time_s is not None:
        _, t = _motion(np.zeros((n, 3)), time_s, n)  # the magnetometer's times checked first
        gyro, dropped, gap_notes = _own_rate(gyro, gyro_time_s, t)
        kept = ~dropped
    w, t = _motion(gyro, time_s, n)
    a = None if accel is None else _accel(accel, n)
    if not kept.all():  # samples the gyro never saw turning: dropped, the stretches restart after them
        y, w, t = y[kept], w[kept], t[kept]
        a = None if a is None else a[kept]
        if y.shape[0] < 50:
            raise CalibrationError(
                f"the samples do not support the gyro calibration: {y.shape[0]} samples are left once those in the "
                f"gyro's gaps are dropped; {_ADVICE}",
                codes=("too_few_samples",),
            )
    if mapping not in ("search", "general") and mapping not in MAPPINGS:
        raise OptionError(
            f"mapping={mapping!r} is not valid; choose 'search', 'general' or one of: {', '.join(MAPPINGS)}"
        )
    if not segment_s > 0:
        raise OptionError(f"segment_s must be positive, got {segment_s!r}")
    if inclination_deg is not None:
        try:
            dip = float(inclination_deg)
        except (TypeError, ValueError):
            dip = math.nan
        if not -90.0 <= dip <= 90.0:  # NaN fails too
            raise OptionError(f"inclination_deg must be the field's dip in degrees within ±90, got {inclination_deg!r}")
        inclination_deg = dip
    length = max(_MIN_WINDOW, round(WINDOW_S / float(np.median(np.diff(t)))))
    win = _windows(y, w, t, length)
    if win.T.size < 20:
        raise CalibrationError(
            f"the samples do not support the gyro calibration: the recording is too short, {win.T.size} windows "
            f"of {length} samples where 20 are needed (about {20 * WINDOW_S:.0f} s); {_ADVICE}",
            codes=("too_few_samples",),
        )
    _check_gyro(w, y)
    if lag_s == "search":
        open_readings = _check_readings(y, w, t)
        lag = _search_lag(y, w, t, length)
    elif isinstance(lag_s, (int, float)) and math.isfinite(lag_s):
        lag = float(lag_s)
        open_readings = _check_readings(y, _delayed(w, t, lag), t, lag_given=True)
    else:
        raise OptionError(f"lag_s must be 'search' or a number of seconds, got {lag_s!r}")
    w = _delayed(w, t, lag)
    inside = (t - lag >= t[0]) & (t - lag <= t[-1])
    if not inside.all():  # the gyro read before its first sample or after its last: held, not measured
        y, w, t = y[inside], w[inside], t[inside]
        a = None if a is None else a[inside]
    win = _windows(y, w, t, length)
    if win.T.size < 20:
        raise CalibrationError(
            f"the samples do not support the gyro calibration: {y.shape[0]} samples are left where the gyro, "
            f"{lag:+.3g} s apart, has a reading; {_ADVICE}",
            codes=("too_few_samples",),
        )
    beta = _windowed_bias(win)[1]
    turns_deg, axes = _turn_axes(win, beta)
    if turns_deg[1] < SINGLE_AXIS * turns_deg[0]:
        raise CalibrationError(
            "the samples do not support the gyro calibration: the vehicle turned about "
            f"{_axis_words(axes[:, 0], 'gyro')} only (its turning about any other axis is "
            f"{100 * turns_deg[1] / turns_deg[0]:.1f} % of that): the kinematics then fix the offset across that "
            "axis and the distortion of the plane perpendicular to it, but the offset and the scale along it move "
            f"with the field's component along it, which never changes, so they are fixed by nothing; {_ADVICE}",
            codes=("single_axis",),
        )
    # The accelerometer on the gyroscope's clock; its still samples gated on the rates with stage 1's bias taken
    # off (a rolling boat has no steady stretch for gravity.still_samples to take it from, and 1°/s of bias
    # then reads as turning on every sample: none was kept on simulated boats).
    gravity, gravity_facts = (None, {}) if a is None else _gravity(_delayed(a, t, lag), y, w - beta, t)
    model, excess, ambiguous = _choose(y, w, t, win, mapping, segment_s, gravity)
    disagreement = None
    if model.traj.gravity is not None and inclination_deg is not None:
        disagreement = _inclination_disagreement(model, inclination_deg)
        gravity_facts["inclination_given_deg"] = float(inclination_deg)
        if disagreement is not None:
            gravity_facts.update({"used": False, "reason": disagreement, **_dip(model)})
            model, excess, ambiguous = _choose(y, w, t, win, mapping, segment_s, None)
    traj, solution = model.traj, model.solution
    p = solution.params
    k = traj.k
    g = traj.distortion(p)
    offset, beta = p[k : k + 3], p[k + 3 : k + 6]
    covariance = _covariance(traj, p)

    strength = abs(float(np.linalg.det(g))) ** (1.0 / 3.0)
    matrix = np.linalg.inv(g) * strength
    if np.linalg.det(matrix) < 0:  # −H fits alike (a field and its negative turn alike): take the proper one
        matrix = -matrix
    if traj.gravity is not None:
        gravity_residual, _ = _gravity_residual(model, traj.gravity)
        gravity_facts.update({
            "weight": traj.gravity.weight,
            "residual_rms_deg": math.degrees(float(np.sqrt(np.mean(gravity_residual**2)))),
            **_dip(model, covariance),
        })  # fmt: skip
    rotation, symmetric = polar_decomposition(matrix)
    nearest = mapping_name(rotation)
    angle = _angle_deg(MAPPINGS[nearest], rotation)

    residual = traj.magnetometer_residual(p)
    residual_rms = float(np.sqrt(np.mean(np.sum(residual**2, axis=1)))) / strength
    if residual_rms > LARGE_RESIDUAL:  # the windows cannot tell the readings apart on a slow vehicle: the fit can
        _check_readings_by_fit(y, t, open_readings, segment_s, residual_rms)
    values, vectors = np.linalg.eigh(covariance[k : k + 3, k : k + 3])
    offset_sigma = np.sqrt(np.clip(values, 0, None)) / strength
    heading_sigma = _heading_sigma(g, offset, covariance, traj)
    field = np.einsum("ij,kj->ki", matrix, y - offset)
    directions = field / np.linalg.norm(field, axis=1)[:, None]
    mean = directions.mean(axis=0)
    spread = np.arccos(np.clip(np.einsum("kj,j->k", directions, mean / max(float(np.linalg.norm(mean)), 1e-12)), -1, 1))
    span_deg = 2.0 * float(np.degrees(spread.max()))
    unused = None if a is None or traj.gravity is not None else str(gravity_facts.get("reason", ""))
    support = _support(ambiguous, offset_sigma, vectors, heading_sigma, residual_rms, span_deg, lag, turns_deg,
                       gravity=traj.gravity is not None, accel_unused=unused,
                       inclination_checked=inclination_deg is not None, disagreement=disagreement,
                       lag_searched=lag_s == "search")  # fmt: skip
    halves = _halves(model, segment_s) if support.verdict != "refused" else None
    if halves is not None and halves[0] > HALVES_SIGMAS * halves[1]:
        support = replace(support, verdict="weak", weaknesses=(*support.weaknesses, Reason(
            f"the two halves of the recording give headings {halves[0]:.2g}° apart (RMS over level headings), "
            f"{halves[0] / max(halves[1], 1e-12):.1f} times their combined one-sigma (±{halves[1]:.2g}°): the field, "
            "the gyro's bias or the clocks changed between them, and the stated one-sigma does not cover that; "
            "expect heading errors of the order of their difference", "inconsistent_halves")))  # fmt: skip
    if mapping in MAPPINGS and excess.get(mapping, 0.0) > LIKELIHOOD_RATIO:
        support = replace(support, verdict="weak" if support.verdict == "supported" else support.verdict,
                          weaknesses=(*support.weaknesses, Reason(
                                      f"the mapping given ({mapping}) fits {excess[mapping]:.0f} noise variances worse "
                                      "than a general rotation of the axes: the mounting is likely turned from it "
                                      "(mapping='search' reports by how much)", "gyro")))  # fmt: skip
    diagonal = np.sqrt(np.clip(np.diag(covariance), 0, None))
    details: dict[str, Any] = {
        "mapping": "general" if model.name == "general" else nearest,
        "mapping_likelihood_ratios": excess,
        "rotation": rotation.tolist(),
        "nearest_mapping": nearest,
        "angle_from_nearest_deg": angle,
        "mirror": "not determined by the kinematics: the magnetometer is taken to be right-handed",
        "sensor_matrix": symmetric.tolist(),
        "gyro_bias": beta.tolist(),
        "gyro_bias_sigma": diagonal[k + 3 : k + 6].tolist(),
        "offset_sigma": diagonal[k : k + 3].tolist(),
        "heading_sigma_deg": heading_sigma,
        "residual_rms": residual_rms,
        "turns_deg": turns_deg.tolist(),
        "segments": traj.count,
        "window_samples": length,
        "lag_s": lag,
        "solver": {"status": solution.status, "iterations": solution.iterations, "message": solution.message},
        "support": support.to_dict(),
    }
    if gravity_facts:
        details["gravity"] = gravity_facts
    if gap_notes:
        details["gyro_gaps"] = gap_notes
    return Calibration("gyro", offset, matrix, strength, n_samples=int(y.shape[0]), details=details, frame="vehicle")
