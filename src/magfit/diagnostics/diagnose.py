"""Diagnose a calibration on its samples or its statistics (:func:`diagnose`, :func:`diagnose_statistics`): the
package docstring of :mod:`magfit.diagnostics` says what and how."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._validation import check_finite, check_shape
from ..calibration import Calibration
from ..errors import MagfitError, SampleError
from ..evaluate import Evaluation, unchecked_sphere_distances
from ..findings import Diagnostics, Goodness, Reason, ReasonList, Support
from ..geometry.frame import Frame
from ..geometry.quadric import algebraic_ellipsoid, calibration_from_ellipsoid
from ..outliers import inlier_mask
from ..sampling import MAX_ANALYSED, thin, weighted_even_subsample
from ..saturation import Clipping, find_clipped
from ..statistics import Statistics
from .coverage import coverage
from .uncertainty import (
    DEFAULT_INCLINATION_DEG,
    Uncertainty,
    analyse,
    compare_with_drift,
    compare_with_full,
    consistency,
    covering,
    level_heading_difference_deg,
)
from .verdict import (
    NO_ELLIPSOID_RMS,
    Evidence,
    halves_apart,
    judge,
    mirrored_offset,
    too_few_for_the_noise,
    two_solutions,
)

__all__ = ["MAX_SAMPLES", "Refit", "diagnose", "diagnose_statistics", "flat_axis", "model_kind"]


#: ``refit(samples) -> Calibration``: the method of a calibration with the user's options.
Refit = Callable[[NDArray[np.float64]], Calibration]

#: The diagnostics of a fit use at most this many samples.
MAX_SAMPLES = MAX_ANALYSED
#: The consistency check refits on at most this many of the analysed samples.
CONSISTENCY_SAMPLES = 5_000
#: Folds of the held-out evaluation, and the most analysed samples it refits on.
FOLDS = 5
GOODNESS_SAMPLES = 3_000


# ---------------------------------------------------------------------- diagnose


def model_kind(calibration: Calibration) -> str:
    """The model family of a calibration: sphere, diag (axis-aligned) or full.

    ``calibration.model`` when it says (every fit does); a vehicle-frame matrix is ``full``. A calibration
    without it (made by hand, or read from a version-1 file) gets the family its ellipsoid has: ``full``
    with cross terms, ``sphere`` with equal axes, ``diag`` otherwise.
    """
    if calibration.model is not None:
        return "full" if calibration.model == "vehicle" else calibration.model
    shape = calibration.ellipsoid_matrix
    scale = float(np.max(np.abs(shape)))
    off_diagonal = shape - np.diag(np.diag(shape))
    if np.max(np.abs(off_diagonal)) > 1e-9 * scale:
        return "full"
    diagonal = np.diag(shape)
    if np.ptp(diagonal) <= 1e-9 * scale:
        return "sphere"
    return "diag"


def diagnose(
    calibration: Calibration,
    samples: ArrayLike,
    *,
    inclination_deg: float = DEFAULT_INCLINATION_DEG,
    max_samples: int = MAX_SAMPLES,
    held_out: bool = True,
    represents: int | None = None,
    refit: Refit | None = None,
    thorough: bool = True,
    compare_ml: bool = True,
    variation_refit: Refit | None = None,
    model_error_heading_deg: float = 0.0,
    model_error_offset: tuple[float, float, float] | None = None,
    clipping: Clipping | None = None,
    fitted_rows: int | None = None,
) -> Diagnostics:
    """Diagnose a calibration on the samples it was fitted to (or on a subsample of them), with its verdict.

    Parameters
    ----------
    calibration : Calibration
        Any calibration.
    samples : array_like, shape (N, 3)
        The raw samples, input units, in recording order (the one-sigmas count the correlation of
        neighbouring samples). Samples a robust fit rejected (``calibration.rejected``) are left out.
    inclination_deg : float
        Magnetic inclination assumed for the heading uncertainty, degrees (default 60°).
    max_samples : int
        Cap on the samples analysed (a spatially even subsample above it).
    held_out : bool
        Also evaluate on held-out samples (k-fold refits with ``refit``).
    represents : int, optional
        When ``samples`` is a regular subsample of a longer recording (e.g. a streamed file), how many
        samples the fit used: the uncertainty is then scaled to all of them.
    refit : callable, optional
        ``refit(samples) -> Calibration``: the calibration's method with the user's options, for the
        held-out evaluation and the two halves of the recording (``magfit.diagnose`` passes it; without
        it those two checks are skipped).
    thorough : bool
        Also run the checks that refit the method: held-out goodness and the two halves. Without them
        (``magfit.fit(..., diagnostics=False)``) the verdict still covers coverage, residuals,
        observability, the known field and the consistency with the maximum-likelihood fit.
    compare_ml : bool
        Compare with the maximum-likelihood fit of the same model (the consistency check). ``auto`` judges
        its candidates without it: they are those fits.
    variation_refit : callable, optional
        The refit for the two halves and the block jackknife (10 refits), when ``refit`` is too slow for
        that many: the same model's first-order maximum-likelihood fit (``magfit.fit`` passes it for the
        iterative methods). Default: ``refit``.
    model_error_heading_deg : float
        A heading error the calibration's model is known to leave out (``auto``: the distortion of a richer
        model the samples do not determine), degrees: added in quadrature to the heading one-sigma before
        the verdict, so that every figure stated is the one uncertainty.
    model_error_offset : tuple of 3 float, optional
        The offset error (input units, per axis) that distortion can cause: added in quadrature to the offset
        one-sigma, as the heading error is to the heading one-sigma.
    clipping : Clipping, optional
        The rows of ``samples`` clipped at the sensor's full scale, as the fit found them on these samples,
        which it has also checked finite (:func:`magfit.fit` passes it): neither pass over the samples is
        made again. None: both are made here.
    fitted_rows : int, optional
        The fit read a regular stride of at most this many of the samples (``auto``'s maximum-likelihood refit:
        :attr:`~magfit.methods.registry.MethodSpec.fit_rows`). On more samples the uncertainty is stated for the
        ``m = ⌈n / ⌈n / fitted_rows⌉⌉`` rows it read: a fit on m of n samples varies n / m times more than a fit
        on all of them, less when neighbouring samples are correlated: the diagnostics read those rows, as the
        recording (the correlation in time of the stride, not of the neighbours).

    Returns
    -------
    Diagnostics
        With ``support``, the verdict of :mod:`magfit.diagnostics.verdict`.
    """
    array = check_shape(samples)  # in the caller's dtype: only the rows analysed become float64
    if clipping is None or clipping.n_samples != array.shape[0]:
        check_finite(array)
        clipping = find_clipped(array)  # the rows every fit left out (methods.core.estimate): so do the diagnostics
    if represents is not None and represents < array.shape[0]:
        raise SampleError(f"represents={represents} is fewer than the {array.shape[0]} samples given")
    notes: list[str] = []
    if clipping.n_clipped:
        notes.append(f"{clipping.n_clipped} samples clipped at the sensor's full scale are left out of these figures.")
        array = array[~clipping.clipped]
    mask, how = inlier_mask(calibration, array)
    if mask is not None and not mask.all():
        notes.append(f"{int((~mask).sum())} samples {how} are left out of the diagnostics.")
        array = array[mask]
    n = array.shape[0]
    total = n if represents is None else max(1, round(represents * n / max(len(mask) if mask is not None else n, 1)))
    if represents is not None:
        notes.append(f"The {n} samples analysed stand for {total} samples: the uncertainty is scaled to those.")
    stated = total  # the samples the fit's uncertainty is for
    if fitted_rows is not None and n > fitted_rows and represents is None:
        # The rows the fit read are the recording its uncertainty is for, their correlation in time too.
        array = array[:: math.ceil(n / fitted_rows)]
        notes.append(
            f"The fit read a regular stride of {array.shape[0]} of the {n} samples: the uncertainty is for those."
        )
        n = stated = array.shape[0]
    candidates = thin(n, max_samples)
    rows = np.asarray(array[candidates], dtype=np.float64)  # a regular stride, in recording order
    z_candidates = Frame.corrected(calibration).normalise(rows)
    chosen, weights = weighted_even_subsample(z_candidates, max_samples, total=stated)
    indices = candidates[chosen]
    raw, z = rows[chosen], z_candidates[chosen]
    if indices.size < n:
        notes.append(
            f"Diagnostics computed on a spatially even subsample of {indices.size} of {n} samples "
            "(weighted to stand for all of them)."
        )
    kind = model_kind(calibration)
    cover = coverage(z)
    pinned = calibration.known_field is not None and calibration.known_field.pinned
    # The correlation in time is read on the recording itself (a bounded part of it: uncertainty.correlation_rows).
    observability, uncertainty = analyse(raw, weights, kind, calibration, inclination_deg, series=array, pinned=pinned)
    fitted = _weighted_evaluation(np.linalg.norm(z, axis=1) - 1.0, weights)
    goodness = check = halves = None
    if compare_ml and uncertainty.offset_sigma is not None:  # an undetermined model has no ML fit to compare
        check = consistency(
            raw[:: max(1, indices.size // CONSISTENCY_SAMPLES)], kind, calibration, uncertainty, inclination_deg
        )
    if thorough:
        goodness = _goodness(fitted, raw, weights, refit if held_out else None)
        vary = variation_refit or refit
        # A biased method's halves differ anyway; auto (no check: its choice is a maximum-likelihood fit) is not.
        if vary is not None and (check.consistent if check is not None else uncertainty.offset_sigma is not None):
            halves = _halves(rows, vary, uncertainty, stated)
        if vary is not None and uncertainty.offset_sigma is not None:
            # After the halves: a change between them is named as such, not hidden in a wider one-sigma.
            uncertainty = _with_block_jackknife(uncertainty, rows, vary, calibration, stated)
    comparison = None
    if uncertainty.offset_sigma is not None:  # a restricted model against the full one on the same samples
        comparison = compare_with_full(raw, weights, kind, calibration, uncertainty, inclination_deg, array)
    drifting = None
    if uncertainty.offset_sigma is not None and not pinned:  # a field strength changing along the recording
        drifting = compare_with_drift(rows, kind, calibration, uncertainty, inclination_deg)
    uncertainty = covering(uncertainty, comparison, check, drifting)  # the heading one-sigma covers known biases too
    if (
        halves is not None
        and halves_apart(halves)[2]
        and _halves_saw_alike(rows, calibration)
        and offset_trend_p_value(rows, kind, calibration) < TREND_LEVEL
    ):
        # The sensor changed along the recording (not only the directions each half saw): by how much is known.
        uncertainty = _with_halves_change(uncertainty, halves[0], calibration)
    if model_error_heading_deg > 0 and uncertainty.heading_sigma_deg is not None:  # auto's left-out distortion
        uncertainty = replace(
            uncertainty,
            heading_sigma_deg=math.hypot(uncertainty.heading_sigma_deg, model_error_heading_deg),
            heading_sigma_max_deg=math.hypot(uncertainty.heading_sigma_max_deg or 0.0, model_error_heading_deg),
        )
    if model_error_offset is not None and uncertainty.offset_sigma is not None:
        widened = np.hypot(np.asarray(uncertainty.offset_sigma), np.asarray(model_error_offset, dtype=np.float64))
        uncertainty = replace(uncertainty, offset_sigma=(float(widened[0]), float(widened[1]), float(widened[2])))
    evidence = Evidence(
        kind=kind,
        residual_rms=fitted.rms,
        ellipsoid_rms=None if kind == "full" else _ellipsoid_rms(raw, weights),
        coverage=cover,
        observability=observability,
        uncertainty=uncertainty,
        known_field=_known_field(calibration),
        consistency=check,
        goodness=goodness,
        halves=halves,
        unit=calibration.unit,
        method=calibration.method,
        field_strength=calibration.field_strength,
        flat=flat_axis(raw, weights),
        axis_ratio=float(np.max(calibration.semi_axes) / np.min(calibration.semi_axes)),
        solver_problem=calibration.solver.problem if calibration.solver is not None else None,
        clipping=clipping if clipping.n_clipped else None,
        comparison=comparison,
        drifting=drifting,
        mirror=mirrored_offset(np.asarray(calibration.offset), *_mean_and_covariance(raw, weights)) if pinned else None,
        offset=tuple(float(v) for v in calibration.offset) if pinned else None,  # type: ignore[arg-type]
        n_samples=total,
    )
    support = judge(evidence)
    return Diagnostics(
        n_samples=total,
        n_used=int(indices.size),
        coverage=cover,
        observability=observability,
        uncertainty=uncertainty,
        goodness=goodness,
        warnings=support.warnings,
        notes=tuple(notes),
        unit=calibration.unit,
        consistency=check,
        support=support,
    )


def _mean_and_covariance(
    raw: NDArray[np.float64], weights: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Weighted mean (3,) and covariance (3, 3) of the samples."""
    return np.average(raw, axis=0, weights=weights), np.cov(raw.T, aweights=weights)


#: Samples whose smallest principal spread is below this share of the largest lie close to a plane.
FLAT_RATIO = 0.25


def flat_axis(raw: NDArray[np.float64], weights: NDArray[np.float64] | None = None) -> tuple[str, float] | None:
    """The axis raw samples hardly extend along and their spread along it over the largest, when below 0.25."""
    return flat_axis_of(np.cov(raw.T, aweights=weights))


def flat_axis_of(covariance: NDArray[np.float64]) -> tuple[str, float] | None:
    """:func:`flat_axis` from the samples' covariance (3, 3)."""
    from ..geometry.frame import axis_words

    spreads, directions = np.linalg.eigh(covariance)
    ratio = float(np.sqrt(max(spreads[0], 0.0) / spreads[2])) if spreads[2] > 0 else 0.0
    if ratio > FLAT_RATIO:
        return None
    direction = directions[:, 0] * np.sign(directions[np.argmax(np.abs(directions[:, 0])), 0])
    return axis_words(direction).lstrip("+"), ratio


def _ellipsoid_rms(raw: NDArray[np.float64], weights: NDArray[np.float64]) -> float | None:
    """RMS sphere distance of the samples under the paper's algebraic ellipsoid (None when there is none).

    What a full ellipsoid leaves of the samples, to tell "the samples lie on no ellipsoid" from "this
    restricted model cannot describe the ellipsoid they lie on".
    """
    found = algebraic_ellipsoid(Statistics.from_samples(raw))
    if isinstance(found, str):
        return None
    reference = calibration_from_ellipsoid("ellipsoid", *found)
    distances = unchecked_sphere_distances(reference, raw)
    return float(np.sqrt(np.sum(weights * distances**2) / np.sum(weights)))


def _known_field(calibration: Calibration) -> tuple[float, float] | None:
    """(given, fitted) field strength when the user gave one and the method kept the fitted value."""
    known = calibration.known_field
    if known is None or known.fitted is None:
        return None
    if known.pinned:
        return None  # the sphere fitted with the radius pinned checked it against the samples itself
    return float(calibration.field_strength), known.fitted


#: Each half of the recording is refitted on at most this many samples.
HALF_SAMPLES = 20_000
#: Contiguous blocks of the block jackknife, and the most samples each refit sees.
JACKKNIFE_BLOCKS = 8
JACKKNIFE_SAMPLES = 2_000


def _with_block_jackknife(
    uncertainty: Uncertainty,
    rows: NDArray[np.float64],
    refit: Refit,
    calibration: Calibration,
    total: int | None = None,
) -> Uncertainty:
    """``uncertainty`` widened to what leaving out one stretch of the recording at a time shows.

    The batch-means covariance sees correlation within a stretch of a twentieth of the recording. What
    varies more slowly (a distortion that drifts with temperature, a field that changes along a flight,
    a model error that depends on which directions a stretch covers) shows when the fit itself is
    repeated without each of :data:`JACKKNIFE_BLOCKS` contiguous blocks: the block jackknife
    (Künsch, Ann. Statist. 17, 1989), ``Var = (K − 1) / K Σ (V₍ₖ₎ − V̄)²`` for the offset V. When it
    exceeds the stated offset variance, every one-sigma is scaled by the mean ratio of the two (the
    heading and scale figures come from the same fit). The refits see a regular stride of at most
    :data:`JACKKNIFE_SAMPLES` rows, their variance scaled by their count over the ``total`` samples the
    stated uncertainty is for (``rows`` may itself be a stride of the recording). The level heading is
    jackknifed the same way (each replicate's RMS level-heading difference from ``calibration``), and the
    heading one-sigma raised to it where it is larger. Refits that fail leave the uncertainty as it is.
    """
    assert uncertainty.offset_sigma is not None
    m = rows.shape[0]
    if m < 10 * JACKKNIFE_BLOCKS:
        return uncertainty
    step = max(1, m // JACKKNIFE_SAMPLES)
    series = rows[::step]
    edges = np.linspace(0, series.shape[0], JACKKNIFE_BLOCKS + 1).astype(np.int64)
    offsets = []
    headings = []
    for block in range(JACKKNIFE_BLOCKS):
        kept = np.concatenate([series[: edges[block]], series[edges[block + 1] :]])
        try:
            replicate = refit(kept)
        except (MagfitError, np.linalg.LinAlgError):
            return uncertainty
        offsets.append(replicate.offset)
        headings.append(level_heading_difference_deg(replicate, calibration, uncertainty.inclination_deg))
    leave_one_out = np.array(offsets)
    spread = np.sum((leave_one_out - leave_one_out.mean(axis=0)) ** 2, axis=0)
    # Refits on s of the ``total`` samples vary total / s times more than the fit on all of them.
    variance = (JACKKNIFE_BLOCKS - 1) / JACKKNIFE_BLOCKS * spread * series.shape[0] / (total or m)
    stated = np.maximum(np.asarray(uncertainty.offset_sigma) ** 2, 1e-300)
    factor = float(np.mean(variance / stated))
    widened = uncertainty.scaled(math.sqrt(factor)) if factor > 1.0 else uncertainty
    # The mean ratio leaves an axis the recording pins worse than the others short (a tilt cone's axis, where the
    # offset trades with the scale: full models 8.5 offset one-sigmas off in the campaign): each offset one-sigma
    # is at least its own axis's jackknife one-sigma.
    assert widened.offset_sigma is not None
    own = np.maximum(np.asarray(widened.offset_sigma, dtype=np.float64), np.sqrt(variance))
    widened = replace(widened, offset_sigma=(float(own[0]), float(own[1]), float(own[2])))
    # The same for the level heading itself, each replicate against the whole fit (for the mean of the
    # replicates: a little wider): a drift along a flight moves the heading more than the offsets' mean ratio says.
    scale = series.shape[0] / (total or m)
    heading = math.sqrt((JACKKNIFE_BLOCKS - 1) / JACKKNIFE_BLOCKS * float(np.sum(np.square(headings))) * scale)
    if widened.heading_sigma_deg is not None and heading > widened.heading_sigma_deg:
        largest = max(widened.heading_sigma_max_deg or heading, heading)
        widened = replace(widened, heading_sigma_deg=heading, heading_sigma_max_deg=largest)
    return widened


#: p-value of the offset-trend F test (:func:`offset_trend_p_value`) below which halves that disagree are a change
#: in time, counted in the one-sigmas.
TREND_LEVEL = 1e-3


#: Halves that share less than this fraction of the directions either reached (cells of the sphere both reached,
#: over those either reached) saw other directions: their disagreement, and a trend in time that follows the
#: directions, tells the directions apart, not a changed sensor.
HALVES_SHARED_DIRECTIONS = 0.5


def _halves_saw_alike(rows: NDArray[np.float64], calibration: Calibration) -> bool:
    """Whether the first and second half of ``rows`` (recording order) reached mostly the same directions
    (:data:`HALVES_SHARED_DIRECTIONS`). A tumble whose offset creeps has halves that saw the same sphere; a
    recording parked in one attitude and then turned, or one that turned through one region and then another
    (a half-covered recording), has halves that disagree because each extrapolates over what the other saw."""
    from ..geometry.cells import partition

    z = Frame.corrected(calibration).normalise(rows)
    middle = z.shape[0] // 2
    cells = partition(100)
    first, second = (set(np.unique(cells.cell(half)).tolist()) for half in (z[:middle], z[middle:]))
    either = first | second
    return bool(either) and len(first & second) >= HALVES_SHARED_DIRECTIONS * len(either)


def offset_trend_p_value(rows: NDArray[np.float64], kind: str, calibration: Calibration) -> float:
    """p-value of an offset that moves linearly along the recording, against ``calibration``'s constant one.

    Halves of a recording can disagree because each saw other directions (a sensor held in a few attitudes in
    turn: each half's fit extrapolates over the other's clusters) or because the sensor changed. Only the
    second leaves the whole recording's fit a trend to explain: with ``τ`` the time from the middle, in
    [−½, ½], and the distances' Jacobian J (N, k) at the calibration (the corrected frame), an offset
    ``V + τ c`` adds the columns ``τ J_V`` (J_V its three offset columns). Projected off J (the constant
    model is at its optimum), the F test of nested least squares with 3 and N − k − 3 degrees of freedom:

        F = (ΔRSS / 3) / (RSS₁ / (N − k − 3))                                                        (T)

    ``rows`` in recording order. Noise correlated in time inflates F: the test only tells the halves' kind
    of disagreement, never names one by itself.
    """
    from scipy.stats import f as f_distribution

    from ..geometry.frame import PARAMETER_NAMES, distance_jacobian

    z = Frame.corrected(calibration).normalise(rows)
    names = PARAMETER_NAMES[kind]
    p = np.array([1.0 if name.startswith("scale") else 0.0 for name in names])  # the identity: the fit itself
    jac = distance_jacobian(p, z, kind)
    residual = np.linalg.norm(z, axis=1) - 1.0
    n, k = jac.shape
    if n < k + 3 + 10:
        return 1.0
    tau = np.linspace(-0.5, 0.5, n)[:, None]
    basis = np.linalg.qr(jac)[0]
    trend = tau * jac[:, :3]
    trend = trend - basis @ (basis.T @ trend)
    residual = residual - basis @ (basis.T @ residual)
    explained = trend @ np.linalg.lstsq(trend, residual, rcond=None)[0]
    reduction = float(explained @ explained)
    remaining = max(float(residual @ residual) - reduction, 1e-300)
    statistic = (reduction / 3.0) / (remaining / (n - k - 3))
    return float(f_distribution.sf(statistic, 3, n - k - 3))


def _with_halves_change(
    uncertainty: Uncertainty, difference: tuple[float, float, float], calibration: Calibration
) -> Uncertainty:
    """``uncertainty`` widened by the change between the two halves of the recording, when they disagree.

    Offsets fitted on the halves differ by ΔV; the whole recording's fit lies between them. A sensor that
    changes steadily (an offset creeping as it warms up) is at the halves' centres (a quarter and three quarters
    of the way) ±ΔV/2 from the whole fit, and at the ends of the recording ±ΔV: that is where the user's next
    readings are (the end state) and where they were (the start), and no noise figure holds it. So, in
    quadrature, as :func:`~magfit.diagnostics.uncertainty.covering` counts a known error,

        σ_V,i² ← σ_V,i² + ΔV_i²,    σ_ψ² ← σ_ψ² + Δψ²                                                    (H)

    Δψ the RMS level-heading difference of the calibration with its offset moved by ΔV. A step change (a magnet
    moved halfway) is ΔV/2 from the whole fit at either end: (H) then covers it twice over.
    """
    if uncertainty.offset_sigma is None or uncertainty.heading_sigma_deg is None:
        return uncertainty
    change = np.asarray(difference, dtype=np.float64)
    moved = replace(calibration, offset=np.asarray(calibration.offset, dtype=np.float64) + change)
    turn = level_heading_difference_deg(moved, calibration, uncertainty.inclination_deg)
    offset = np.hypot(np.asarray(uncertainty.offset_sigma, dtype=np.float64), change)
    return replace(
        uncertainty,
        offset_sigma=(float(offset[0]), float(offset[1]), float(offset[2])),
        heading_sigma_deg=math.hypot(uncertainty.heading_sigma_deg, turn),
        heading_sigma_max_deg=math.hypot(uncertainty.heading_sigma_max_deg or uncertainty.heading_sigma_deg, turn),
    )


def _halves(
    rows: NDArray[np.float64], refit: Refit, uncertainty: Uncertainty, total: int | None = None
) -> tuple[tuple[float, float, float], tuple[float, float, float]] | None:
    """Offset of the second half of the recording minus the first's, and the one-sigma of that difference.

    Each half holds half the samples, so its offset has √2 times the whole recording's one-sigma (the
    honest one, with the correlation in time counted); their difference 2 times (more when a half is
    refitted on a stride of it: a fit on s of the ``total`` samples the one-sigma is for varies total / s
    times more, and ``rows`` may itself be a stride of the recording). None when a half cannot be fitted
    (too few samples, or too few directions in one half: that is the coverage's to report).
    """
    if uncertainty.offset_sigma is None or rows.shape[0] < 100:
        return None
    middle = rows.shape[0] // 2
    offsets = []
    variance_factor = 0.0  # Var(difference) / Var(whole recording's offset)
    for half in (rows[:middle], rows[middle:]):
        step = max(1, half.shape[0] // HALF_SAMPLES)
        fitted_on = half[::step]
        try:
            offsets.append(refit(fitted_on).offset)
        except (MagfitError, np.linalg.LinAlgError):
            return None
        # A fit on s of the total samples varies total / s times more than the whole recording's.
        variance_factor += (total or rows.shape[0]) / fitted_on.shape[0]
    difference = offsets[1] - offsets[0]
    sigma = math.sqrt(variance_factor) * np.asarray(uncertainty.offset_sigma)
    return (
        (float(difference[0]), float(difference[1]), float(difference[2])),
        (float(sigma[0]), float(sigma[1]), float(sigma[2])),
    )


def diagnose_statistics(calibration: Calibration, statistics: Statistics) -> Diagnostics:
    """What a :class:`~magfit.Statistics` allows: the verdict and the weak directions, from the moments.

    See :mod:`magfit.diagnostics.moments`: the directions are named, without one-sigmas (the algebraic
    residual would understate them); a direction with less than 1/1000 of a full tumble's information is
    not determined (refused), as are samples whose algebraic residual exceeds what any ellipsoid leaves.
    Coverage, uncertainty, consistency and held-out goodness need the samples, and the result says so.
    """
    from .moments import analyse_statistics

    observability, mean, std = analyse_statistics(statistics, calibration, model_kind(calibration))
    refusals = ReasonList()
    if few := too_few_for_the_noise(statistics.n, model_kind(calibration)):
        refusals.add("too_few_samples", few)
    undetermined = [w.description for w in observability.weak if not w.determined]
    known = calibration.known_field
    flat = flat_axis_of(statistics.covariance)
    if undetermined and known is not None and known.pinned and flat is not None:
        # The field strength was given: what is open is the sign of the field's component along the turning axis.
        mirror = mirrored_offset(np.asarray(calibration.offset), statistics.centre, statistics.covariance)
        label = f" {calibration.unit}" if calibration.unit else ""
        refusals.add("undetermined", two_solutions(calibration.offset, mirror, flat[0], label))
    elif undetermined:
        words = "; ".join(undetermined)
        refusals.add("undetermined", f"the samples do not determine {words}: those numbers would be noise")
    if std > NO_ELLIPSOID_RMS:
        best = std if model_kind(calibration) == "full" else _algebraic_ellipsoid_std(statistics)
        if best is not None and best <= NO_ELLIPSOID_RMS:
            refusals.add("model_inadequate",
                f"the {calibration.method} fit cannot describe these samples: its algebraic distance to them is "
                f"{100 * std:.0f} % of the field (RMS) where a full ellipsoid's is {100 * best:.1f} %; the auto or "
                "ellipsoid method would not leave that"
            )
        else:
            refusals.add("no_ellipsoid",
                f"the samples lie on no ellipsoid: their algebraic distance to the fitted one is {100 * std:.0f} % of "
                "the field (RMS)"
            )
    weaknesses = [
        Reason(f"{w.description} is weakly determined", "weakly_determined") for w in observability.weak if w.determined
    ]
    support = Support.judged(
        refusals, weaknesses, "record again turning the sensor through all attitudes (a full tumble is best)"
    )
    return Diagnostics(
        n_samples=statistics.n,
        n_used=statistics.n,
        coverage=None,
        observability=observability,
        uncertainty=None,
        goodness=None,
        warnings=support.warnings,
        notes=(
            f"Fitted from Statistics: the weak directions come from the moments (algebraic residual: mean "
            f"{mean:+.4f}, std {std:.4f} of the field); coverage, uncertainty, consistency and held-out goodness "
            "need the samples: run magfit.diagnose(calibration, samples) on (a subsample of) them.",
        ),
        unit=calibration.unit,
        support=support,
    )


def _algebraic_ellipsoid_std(statistics: Statistics) -> float | None:
    """The algebraic residual's spread under the paper's ellipsoid of ``statistics`` (None: there is none)."""
    from .moments import analyse_statistics

    found = algebraic_ellipsoid(statistics)
    if isinstance(found, str):
        return None
    _, _, std = analyse_statistics(statistics, calibration_from_ellipsoid("ellipsoid", *found), "full")
    return float(std)


def _weighted_evaluation(distances: NDArray[np.float64], weights: NDArray[np.float64]) -> Evaluation:
    total = float(weights.sum())
    mean = float(np.sum(weights * distances) / total)
    magnitude = np.abs(distances)
    return Evaluation(
        n=round(total),
        mean=mean,
        std=float(np.sqrt(np.sum(weights * (distances - mean) ** 2) / total)),
        mean_abs=float(np.sum(weights * magnitude) / total),
        rms=float(np.sqrt(np.sum(weights * distances**2) / total)),
        max_abs=float(magnitude.max()),
    )


def _goodness(
    fitted: Evaluation,
    raw: NDArray[np.float64],
    weights: NDArray[np.float64],
    refit: Refit | None,
) -> Goodness:
    """The paper's metric on the fitted samples and, with ``refit``, on held-out ones (k-fold refits)."""
    if refit is None:
        return Goodness(fitted, None, 0, "no refit of the method was given (or not requested)")
    step = max(1, raw.shape[0] // GOODNESS_SAMPLES)
    raw, weights = raw[::step], weights[::step]
    n = raw.shape[0]
    if n < 10 * FOLDS:
        return Goodness(fitted, None, 0, f"too few samples ({n}) for {FOLDS}-fold cross-validation")
    fold = np.arange(n) % FOLDS  # interleaved folds: each fold spans the whole recording
    distances = np.empty(n)
    for k in range(FOLDS):
        test = fold == k
        try:
            model = refit(raw[~test])
        except MagfitError as error:
            return Goodness(fitted, None, 0, f"the refit on {FOLDS - 1} of {FOLDS} folds failed: {error}")
        distances[test] = unchecked_sphere_distances(model, raw[test])
    note = (
        f"{FOLDS}-fold cross-validation on {n} of the analysed samples: each fold evaluated with the method "
        "refitted on the other four."
    )
    return Goodness(fitted, _weighted_evaluation(distances, weights), FOLDS, note)
