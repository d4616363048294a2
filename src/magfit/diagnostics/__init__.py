"""Honest diagnostics for every calibration: coverage, observability, uncertainty and goodness of fit.

``magfit.fit`` attaches them to every calibration (``calibration.details["diagnostics"]``, read back
typed with ``calibration.diagnostics``); :func:`diagnose` computes them for any calibration and samples.

To keep ``fit`` fast on long logs, the diagnostics run on a capped, spatially even subsample (at most
:data:`MAX_SAMPLES` samples, the same number from every direction cell where possible, each row
weighted by how many samples it stands for so that the uncertainty still reflects all of them). See
``docs/diagnostics.md`` for what each figure means and what to do about it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._validation import check_finite, check_shape
from ..errors import CalibrationError, MagfitError, SampleError
from ..evaluate import Evaluation, unchecked_sphere_distances
from ._geometry import Frame
from .coverage import Coverage, coverage, partition
from .uncertainty import (
    DEFAULT_INCLINATION_DEG,
    Consistency,
    Observability,
    Uncertainty,
    WeakDirection,
    analyse,
    consistency,
)

if TYPE_CHECKING:
    from ..calibration import Calibration
    from ..statistics import Statistics

__all__ = [
    "MAX_SAMPLES",
    "Consistency",
    "Coverage",
    "Diagnostics",
    "Goodness",
    "Observability",
    "Uncertainty",
    "WeakDirection",
    "attach_diagnostics",
    "diagnose",
    "diagnose_statistics",
    "thin",
    "weighted_even_subsample",
]

#: The diagnostics of a fit use at most this many samples.
MAX_SAMPLES = 20_000
#: The consistency check refits on at most this many of the analysed samples.
CONSISTENCY_SAMPLES = 5_000
#: Folds of the held-out evaluation.
FOLDS = 5
_SCHEMA = 1


@dataclass(frozen=True)
class Goodness:
    """The paper's section V metric on the fitted samples and on held-out samples.

    Attributes
    ----------
    fitted : Evaluation
        Sphere distances of the samples the calibration was fitted to (``magfit.evaluate``).
    held_out : Evaluation or None
        The same for samples left out of the fit: ``folds``-fold cross-validation, each fold evaluated
        with the method refitted on the other folds (None when a refit failed or is not possible).
    folds : int
        Number of folds (0 when there was no held-out evaluation).
    note : str
        How it was computed, or why there is no held-out figure.
    """

    fitted: Evaluation
    held_out: Evaluation | None
    folds: int
    note: str

    def to_dict(self) -> dict[str, Any]:
        return {
            "fitted": self.fitted.to_dict(),
            "held_out": None if self.held_out is None else self.held_out.to_dict(),
            "folds": self.folds,
            "note": self.note,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Goodness:
        held_out = data.get("held_out")
        return cls(
            fitted=Evaluation(**data["fitted"]),
            held_out=None if held_out is None else Evaluation(**held_out),
            folds=int(data["folds"]),
            note=str(data["note"]),
        )

    def summary(self) -> list[str]:
        lines = [
            f"Goodness (distance to the unit sphere, paper section V): fitted samples mean "
            f"{self.fitted.mean:+.4f}, std {self.fitted.std:.4f}."
        ]
        if self.held_out is None:
            lines.append(f"No held-out evaluation: {self.note}")
            return lines
        lines.append(
            f"Held-out samples ({self.folds}-fold cross-validation): mean {self.held_out.mean:+.4f}, "
            f"std {self.held_out.std:.4f}."
        )
        if self.held_out.std > 1.25 * self.fitted.std:
            lines.append(
                "The held-out spread is clearly larger than the fitted one: the model follows the noise of "
                "these samples (too many parameters for the coverage); prefer a simpler method or record more "
                "directions."
            )
        return lines


@dataclass(frozen=True)
class Diagnostics:
    """Everything magfit can say about how trustworthy a calibration is.

    Attributes
    ----------
    n_samples : int
        Samples the calibration was fitted to (outliers the fit rejected excluded).
    n_used : int
        Samples the diagnostics looked at (a spatially even subsample when more than 20 000).
    coverage, observability, uncertainty, goodness
        The four parts (None when the input did not allow them, e.g. a fit from ``Statistics``).
    consistency : Consistency or None
        The distance to the maximum-likelihood fit of the same model (shows an estimator's bias).
    warnings : tuple of str
        The findings that should stop a user from trusting the calibration as it is.
    notes : tuple of str
        How the diagnostics were computed (subsample, statistics only ...).
    """

    n_samples: int
    n_used: int
    coverage: Coverage | None
    observability: Observability | None
    uncertainty: Uncertainty | None
    goodness: Goodness | None
    warnings: tuple[str, ...]
    notes: tuple[str, ...]
    unit: str | None = None
    consistency: Consistency | None = None

    @property
    def ok(self) -> bool:
        """True when there is no warning."""
        return not self.warnings

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict (the layout stored in ``calibration.details["diagnostics"]``)."""
        return {
            "schema_version": _SCHEMA,
            "n_samples": self.n_samples,
            "n_used": self.n_used,
            "coverage": None if self.coverage is None else self.coverage.to_dict(),
            "observability": None if self.observability is None else self.observability.to_dict(),
            "uncertainty": None if self.uncertainty is None else self.uncertainty.to_dict(),
            "goodness": None if self.goodness is None else self.goodness.to_dict(),
            "warnings": list(self.warnings),
            "notes": list(self.notes),
            "unit": self.unit,
            "consistency": None if self.consistency is None else self.consistency.to_dict(),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Diagnostics:
        """Inverse of :meth:`to_dict`."""
        if data.get("schema_version") != _SCHEMA:
            raise MagfitError(
                f"diagnostics schema version {data.get('schema_version')!r} is not supported (expected {_SCHEMA})"
            )
        try:
            return cls(
                n_samples=int(data["n_samples"]),
                n_used=int(data["n_used"]),
                coverage=None if data["coverage"] is None else Coverage.from_dict(data["coverage"]),
                observability=None if data["observability"] is None else Observability.from_dict(data["observability"]),
                uncertainty=None if data["uncertainty"] is None else Uncertainty.from_dict(data["uncertainty"]),
                goodness=None if data["goodness"] is None else Goodness.from_dict(data["goodness"]),
                warnings=tuple(data["warnings"]),
                notes=tuple(data["notes"]),
                unit=data.get("unit"),
                consistency=None if data.get("consistency") is None else Consistency.from_dict(data["consistency"]),
            )
        except (KeyError, TypeError) as error:
            raise MagfitError(f"diagnostics are malformed: {error}") from None

    def summary(self) -> list[str]:
        """Plain-language lines, warnings first."""
        lines = [f"WARNING: {warning}" for warning in self.warnings]
        for part in (self.coverage, self.observability):
            if part is not None:
                lines.extend(part.summary())
        if self.uncertainty is not None:
            lines.extend(self.uncertainty.summary(self.unit))
        if self.consistency is not None:
            lines.extend(self.consistency.summary(self.unit))
        if self.goodness is not None:
            lines.extend(self.goodness.summary())
        lines.extend(self.notes)
        return lines


# ---------------------------------------------------------------------- subsample


def thin(n: int, cap: int = MAX_SAMPLES) -> NDArray[np.int64]:
    """At most ``10 cap`` of ``n`` row indices, by a regular stride (cheap on 10⁷ samples)."""
    return np.arange(0, n, max(1, math.ceil(n / (10 * cap))), dtype=np.int64)


def weighted_even_subsample(
    directions: NDArray[np.float64], cap: int = MAX_SAMPLES, total: int | None = None
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Indices of at most ``cap`` rows spread evenly over directions, and the weight of each.

    The rows (already thinned with :func:`thin` when there are many) are binned into 400 equal-area
    direction cells; every cell gives the same number q of its rows, spread in time (all of them when it
    has fewer), with q as large as the cap allows. The weight of a row is the number of original rows it
    stands for: its cell's count over the rows taken there, times ``total / len(directions)``, so the
    weights sum to ``total`` (default: the number of rows).
    """
    m = directions.shape[0]
    factor = 1.0 if total is None else total / max(m, 1)
    if m <= cap:
        return np.arange(m, dtype=np.int64), np.full(m, factor)
    cells = partition(400).cell(directions)
    order = np.argsort(cells, kind="stable")  # by cell, in time order within a cell
    counts = np.bincount(cells, minlength=400)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    low, high = 1, int(counts.max())
    while low < high:  # the largest q with Σ min(count, q) <= cap
        middle = (low + high + 1) // 2
        if int(np.minimum(counts, middle).sum()) <= cap:
            low = middle
        else:
            high = middle - 1
    taken = np.minimum(counts, low)
    occupied = np.flatnonzero(counts)
    positions = np.concatenate(
        [starts[cell] + np.arange(taken[cell]) * counts[cell] // taken[cell] for cell in occupied]
    )
    indices = order[positions]
    chosen_cells = cells[indices]
    weights = counts[chosen_cells] / taken[chosen_cells] * factor
    sort = np.argsort(indices)
    return np.asarray(indices[sort], dtype=np.int64), np.asarray(weights[sort], dtype=np.float64)


# ---------------------------------------------------------------------- diagnose


def _model_kind(calibration: Calibration) -> str:
    """The model family of a calibration, from its structure: sphere, diag (axis-aligned) or full."""
    shape = calibration.ellipsoid_matrix
    scale = float(np.max(np.abs(shape)))
    off_diagonal = shape - np.diag(np.diag(shape))
    if np.max(np.abs(off_diagonal)) > 1e-9 * scale:
        return "full"
    diagonal = np.diag(shape)
    if np.ptp(diagonal) <= 1e-9 * scale:
        return "sphere"
    return "diag"


def _inlier_mask(calibration: Calibration, samples: NDArray[Any]) -> tuple[NDArray[np.bool_] | None, str]:
    """The samples a robust fit kept (None: all), and how they were found.

    The recorded indices when they refer to these samples; otherwise (a subsample, a truncated list) the
    robust fit's own rule applied again: ``|r − median(r)| > threshold · 1.4826 MAD(r)``.
    """
    stored = calibration.details.get("rejected")
    if not isinstance(stored, dict):
        return None, ""
    n = samples.shape[0]
    if not stored.get("truncated") and calibration.n_samples == n:
        mask = np.ones(n, dtype=bool)
        for start, stop in stored.get("runs", []):
            mask[int(start) : int(stop)] = False
        return mask, "the robust fit rejected"
    residuals = unchecked_sphere_distances(calibration, samples)
    centre = float(np.median(residuals))
    sigma = 1.4826 * float(np.median(np.abs(residuals - centre)))
    threshold = float(calibration.details.get("threshold", 3.5))
    return np.abs(residuals - centre) <= threshold * max(sigma, 1e-12), "lie beyond the robust fit's threshold"


def diagnose(
    calibration: Calibration,
    samples: ArrayLike,
    *,
    inclination_deg: float = DEFAULT_INCLINATION_DEG,
    max_samples: int = MAX_SAMPLES,
    held_out: bool = True,
    represents: int | None = None,
) -> Diagnostics:
    """Diagnose a calibration on the samples it was fitted to (or on a subsample of them).

    Parameters
    ----------
    calibration : Calibration
        Any calibration (its method is refitted for the held-out evaluation when it is a registered one).
    samples : array_like, shape (N, 3)
        The raw samples, input units. Samples a robust fit rejected (``details["rejected"]``) are left out.
    inclination_deg : float
        Magnetic inclination assumed for the heading uncertainty, degrees (default 60°).
    max_samples : int
        Cap on the samples analysed (a spatially even subsample above it).
    held_out : bool
        Also evaluate on held-out samples (k-fold refits of the method).
    represents : int, optional
        When ``samples`` is a regular subsample of a longer recording (e.g. a streamed file), how many
        samples the fit used: the uncertainty is then scaled to all of them (assuming the subsample is
        representative and the samples independent).

    Returns
    -------
    Diagnostics
    """
    array = check_shape(samples)  # in the caller's dtype: only the rows analysed become float64
    check_finite(array)
    if represents is not None and represents < array.shape[0]:
        raise SampleError(f"represents={represents} is fewer than the {array.shape[0]} samples given")
    mask, how = _inlier_mask(calibration, array)
    notes: list[str] = []
    if mask is not None and not mask.all():
        notes.append(f"{int((~mask).sum())} samples {how} are left out of the diagnostics.")
        array = array[mask]
    n = array.shape[0]
    total = n if represents is None else max(1, round(represents * n / max(len(mask) if mask is not None else n, 1)))
    if represents is not None:
        notes.append(f"The {n} samples analysed stand for {total} samples: the uncertainty is scaled to those.")
    candidates = thin(n, max_samples)
    rows = np.asarray(array[candidates], dtype=np.float64)
    z_candidates = Frame.corrected(calibration).normalise(rows)
    chosen, weights = weighted_even_subsample(z_candidates, max_samples, total=total)
    indices = candidates[chosen]
    raw, z = rows[chosen], z_candidates[chosen]
    if indices.size < n:
        notes.append(
            f"Diagnostics computed on a spatially even subsample of {indices.size} of {n} samples "
            "(weighted to stand for all of them)."
        )
    kind = _model_kind(calibration)
    cover = coverage(z)
    observability, uncertainty = analyse(raw, weights, kind, calibration, inclination_deg)
    goodness = _goodness(calibration, raw, z, weights, held_out)
    check = None
    if uncertainty.offset_sigma is not None:  # an undetermined model has no maximum-likelihood fit to compare
        check = consistency(
            raw[:: max(1, indices.size // CONSISTENCY_SAMPLES)], kind, calibration, uncertainty, inclination_deg
        )
    warnings = _warnings(cover, observability, goodness)
    if check is not None and not check.consistent:
        warnings.append(
            f"the fit is {check.sigmas:.0f} one-sigmas ({check.heading_difference_deg:.2g}° of level heading) away "
            "from the maximum-likelihood fit of the same model: the method is biased on these samples; prefer "
            "method='auto' (or 'ml', 'als')"
        )
    return Diagnostics(
        n_samples=total,
        n_used=int(indices.size),
        coverage=cover,
        observability=observability,
        uncertainty=uncertainty,
        goodness=goodness,
        warnings=tuple(warnings),
        notes=tuple(notes),
        unit=calibration.unit,
        consistency=check,
    )


def diagnose_statistics(calibration: Calibration, statistics: Statistics) -> Diagnostics:
    """What a :class:`~magfit.Statistics` allows: the weakly determined directions, from the moments.

    See :mod:`magfit.diagnostics.moments`: the directions are named, without one-sigmas (the algebraic
    residual would understate them); coverage, uncertainty, consistency and held-out goodness need the
    samples, and the result says so.
    """
    from .moments import analyse_statistics

    observability, mean, std = analyse_statistics(statistics, calibration, _model_kind(calibration))
    undetermined = [w.description for w in observability.weak if not w.determined]
    warnings = (
        (f"the samples do not determine {'; '.join(undetermined)}: those numbers are noise; record more attitudes",)
        if undetermined
        else ()
    )
    return Diagnostics(
        n_samples=statistics.n,
        n_used=statistics.n,
        coverage=None,
        observability=observability,
        uncertainty=None,
        goodness=None,
        warnings=warnings,
        notes=(
            f"Fitted from Statistics: the weak directions come from the moments (algebraic residual: mean "
            f"{mean:+.4f}, std {std:.4f} of the field); coverage, uncertainty, consistency and held-out goodness "
            "need the samples: run magfit.diagnose(calibration, samples) on (a subsample of) them.",
        ),
        unit=calibration.unit,
    )


def attach_diagnostics(calibration: Calibration, samples: NDArray[Any] | None, statistics: Statistics) -> Calibration:
    """``calibration`` with its diagnostics in ``details["diagnostics"]`` (what :func:`magfit.fit` returns).

    A diagnosis that fails (a degenerate calibration) is recorded as a warning, never raised: the fit
    itself succeeded.
    """
    from dataclasses import replace

    try:
        report = diagnose(calibration, samples) if samples is not None else diagnose_statistics(calibration, statistics)
    except (MagfitError, np.linalg.LinAlgError) as error:
        n = statistics.n
        report = Diagnostics(n, 0, None, None, None, None, (f"the diagnostics could not be computed: {error}",), ())
    return replace(calibration, details={**calibration.details, "diagnostics": report.to_dict()})


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
    calibration: Calibration,
    raw: NDArray[np.float64],
    z: NDArray[np.float64],
    weights: NDArray[np.float64],
    held_out: bool,
) -> Goodness:
    fitted = _weighted_evaluation(np.linalg.norm(z, axis=1) - 1.0, weights)
    if not held_out:
        return Goodness(fitted, None, 0, "not requested")
    refit = _refitter(calibration)
    if refit is None:
        return Goodness(fitted, None, 0, f"method {calibration.method!r} cannot be refitted on part of the samples")
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
        f"{FOLDS}-fold cross-validation on the analysed samples: each fold evaluated with the method refitted "
        "on the other four."
    )
    return Goodness(fitted, _weighted_evaluation(distances, weights), FOLDS, note)


def _refitter(calibration: Calibration) -> Any:
    """A function refitting ``calibration``'s method (with its recorded options) on (n, 3) samples."""
    from ..methods import METHODS, FitInput
    from ..statistics import Statistics

    name = calibration.method
    if name not in METHODS:
        return None
    spec = METHODS[name]
    options = {key: calibration.details[key] for key in spec.options if key in calibration.details}
    if name == "auto" and "chosen_model" in calibration.details:
        from ..methods.auto import fit_chosen

        chosen = str(calibration.details["chosen_model"])
        return lambda samples: fit_chosen(chosen, samples)

    def run(samples: NDArray[np.float64]) -> Calibration:
        statistics = Statistics.from_samples(samples)
        try:
            return spec.function(FitInput(statistics, samples), **options)
        except TypeError as error:  # an option recorded in another form than the method takes
            raise CalibrationError(f"cannot refit {name!r} with options {options}: {error}") from None

    return run


def _warnings(cover: Coverage, observability: Observability, goodness: Goodness) -> list[str]:
    warnings = []
    if cover.share < 0.5:
        warnings.append(
            f"the samples cover only {100 * cover.share:.0f} % of the directions: the calibration is extrapolated "
            "over the rest; record a fuller tumble"
        )
    for axis in cover.unseen_axes:
        warnings.append(
            f"no samples with the field near +{axis} or −{axis}: the sensor only turned about {axis}, so the offset "
            f"and scale along {axis} are not determined by the samples; tilt the sensor so both ends of {axis} face "
            "the field"
        )
    undetermined = [w for w in observability.weak if not w.determined]
    if undetermined:
        parts = "; ".join(w.description for w in undetermined)
        turn = f" (the sensor only turned about {observability.turn_axis})" if observability.turn_axis else ""
        warnings.append(
            f"the samples do not determine {parts}{turn}: those numbers are noise; record more attitudes (tilt the "
            "sensor further); the heading uncertainty includes them"
        )
    if goodness.held_out is not None and goodness.held_out.std > 1.25 * goodness.fitted.std:
        warnings.append("the fit does much better on its own samples than on held-out ones: it is over-fitted")
    return warnings
