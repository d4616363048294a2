"""The support verdict: do the samples determine the calibration that was fitted to them?

Every fit, from every method, is judged in the frame of the calibration it returned, before it is
returned (:func:`magfit.fit`). The verdict is one of three:

- ``"supported"``: every parameter of the model is determined and the samples lie on its ellipsoid
  within a few per cent of the field;
- ``"weak"``: returned, with warnings that name what is weak, in words, with the heading error it can
  cause;
- ``"refused"``: :class:`~magfit.CalibrationError` (exit 1 on the command line), naming what is missing
  and what to record. ``allow_undetermined=True`` (``--force``) returns the calibration all the same,
  with the refusal among its warnings.

What is checked, in this order (each a refusal unless said otherwise):

1. The samples lie on an ellipsoid at all: the RMS distance of the samples to the best ellipsoid (the
   fit itself, or for the sphere and axis-aligned models the full algebraic ellipsoid as well) is below
   :data:`NO_ELLIPSOID_RMS` of the field. A turned sensor in a steady field gives 0.5-5 % (the real
   recordings in ``shared/data/real``: 0.4-4 %; simulated noise of 10 %, 10 %); a Gaussian cloud 39 %, a
   filled cube 28 %, a still sensor's noise 40 %. Between :data:`LARGE_RESIDUAL_RMS` and that: weak. A
   restricted model (sphere, axis-aligned, min/max) that leaves more than that where the full ellipsoid
   fits cannot describe the samples: refused too. Below it, a restricted model is compared with the full
   ellipsoid on the same samples (:class:`~magfit.diagnostics.uncertainty.ModelComparison`, an F test):
   when the full one holds distortion the restricted one cannot (p < 0.001) and pins the level heading
   more than :data:`MODEL_HEADING_DEG` away, refused; otherwise named, what it may cost already in the
   heading one-sigma. A full model the samples do not determine tells nothing here (its fit follows the
   noise along the directions it lacks): the restricted model's own observability and coverage judge it.
2. The sensor did not turn about one axis only: the field directions do not form a band or a cone
   around an axis (then the offset and scale along that axis are fixed by nothing, whatever the
   information matrix says at a fitted point).
3. The information matrix of the returned model at the returned calibration: a combination of
   parameters whose one-sigma (with the correlation of samples in time and the model error counted,
   :func:`magfit.diagnostics.uncertainty.correlation_excess`) exceeds 5 % of the field is not
   determined; one with less than 5 % of the information a full tumble gives is weak. An undetermined
   combination is refused unless the heading uncertainty at level that the whole covariance leaves
   (that combination included) is within :data:`UNDETERMINED_HEADING_DEG`: a vehicle tilted ±20° does
   not pin the scale along z apart from the offset along z (one-sigma 20-30 % of the field), but the
   samples pin their sum where the field was seen, and the level heading to ±1.5° (the benchmark's
   generic sensor: the forced ``ml`` fit 1.4° RMS; holding that combination at the sphere's value or at
   an isotropic z scale instead gave 2.5° and 2.1°, and offsets 55-75 % of the field off, against
   10-30 % free). Such a fit of the full model is returned as weak, the combination named with its
   one-sigma and the attitudes it holds for. Not a restricted model's: its stated uncertainty leaves out
   the soft iron it cannot hold.
4. A known field strength the samples contradict by more than :data:`FIELD_TOLERANCE` (usually a unit
   mix-up, which is named).
5. A fit more than :data:`BIASED_HEADING_DEG` of level heading, or :data:`BIASED_OFFSET` of the field in
   offset, away from the maximum-likelihood fit of its own model (beyond the uncertainty): the method is
   biased on these samples (min/max, or an algebraic fit of a cap of directions).
6. Weak only: a restricted model (sphere, axis-aligned) that misses distortion the full ellipsoid
   shows (the F test above, within the refusal); rows clipped at the sensor's full scale, left out of the
   fit (:mod:`magfit.saturation`; with a refusal, named as its cause); coverage below half the
   directions; a fit that does much worse on held-out samples than on its own (over-fitted); a fit far
   from the maximum-likelihood fit of its model (biased); two halves of the recording that give different
   offsets (the distortion changed while recording).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..findings import Consistency, Coverage, Goodness, Observability, ReasonList, Support, Uncertainty
from ..remedy import option
from ..saturation import Clipping
from .uncertainty import DriftComparison, ModelComparison

__all__ = [
    "FIELD_TOLERANCE",
    "LARGE_RESIDUAL_RMS",
    "NO_ELLIPSOID_RMS",
    "USELESS_BOUND_DEG",
    "Evidence",
    "halves_apart",
    "judge",
    "mirrored_offset",
    "too_few_for_the_noise",
    "two_solutions",
    "unit_mixup",
]

#: RMS distance to the best ellipsoid (fraction of the field) above which the samples lie on no ellipsoid.
NO_ELLIPSOID_RMS = 0.15
#: A fitted ellipsoid longer than this many times its thickness is no soft iron (the paper's steel case: 7).
MAX_AXIS_RATIO = 20.0
#: RMS distance above which the residuals are large enough to name (weak).
LARGE_RESIDUAL_RMS = 0.05
#: A known field strength further than this (relative) from the fitted one is contradicted by the samples.
FIELD_TOLERANCE = 0.15
#: A restricted model is named as missing the soft iron when its residual is this many times the full one's.
RESTRICTED_RESIDUAL_RATIO = 2.0
#: A fit further than this from the maximum-likelihood fit of its own model (degrees of level heading) is
#: refused as biased; closer, it is named.
BIASED_HEADING_DEG = 5.0
#: ... or further than this in offset (fraction of the field), beyond its uncertainty.
BIASED_OFFSET = 0.05
#: An undetermined combination of parameters is returned (weak) when the level heading uncertainty stays
#: within this, degrees; above, refused.
UNDETERMINED_HEADING_DEG = 3.0
#: A restricted model that misses distortion the samples show (the F test against the full model) is refused
#: when what that costs the level heading exceeds this, degrees; below, it is weak, the cost counted in its
#: heading uncertainty.
MODEL_HEADING_DEG = 3.0
#: A calibration whose level heading one-sigma exceeds this, degrees, is refused: a bound that wide tells the
#: user nothing a compass without calibration would not (``auto`` refuses its choice on the same bound).
USELESS_BOUND_DEG = 10.0
#: Halves of a recording whose offsets differ by more than this many combined one-sigmas disagree (the largest of
#: the three axes). With honest one-sigmas a clean recording exceeds it in about 0.8 % of fits (3 × 2Φ(−3));
#: the real Betaflight recording of shared/data/real whose halves are 5 of their own one-sigmas apart lies
#: between 3 and 3.5 here. A reference fit's halves have their own bound (:mod:`magfit.diagnostics.reference`).
HALVES_SIGMAS = 3.0
#: The same test on all three axes at once (:func:`halves_apart`): the root sum of squares of the axes' distances
#: is √χ²₃ for a clean recording, beyond this in 0.8 % of fits (√χ²₃ at 0.992, the largest axis's rate). An offset
#: that creeps along every axis a little (a sensor warming up) passes each axis's bound and not this one.
HALVES_RSS_SIGMAS = 3.44
#: Samples beyond the model's numbers needed to measure the noise the one-sigmas scale by: with ν residual
#: degrees of freedom the estimated variance is σ² χ²_ν / ν, below a ninth of σ² (a one-sigma three times too
#: small) with probability 1 % at ν = 5 and 8 % at ν = 1; with none (as many samples as numbers) the fit passes
#: through every sample and states a one-sigma of zero.
MIN_RESIDUAL_DOF = 5
#: The numbers each model fits (eq. 4's centre and scales: the sphere's 4, six for an axis-aligned ellipsoid,
#: nine for the full one up to its scale).
MODEL_PARAMETERS = {"sphere": 4, "diag": 6, "full": 9}


def too_few_for_the_noise(n_samples: int, kind: str) -> str | None:
    """Why ``n_samples`` cannot support a ``kind`` fit's one-sigmas (:data:`MIN_RESIDUAL_DOF`), or None."""
    needed = MODEL_PARAMETERS.get(kind, 9) + MIN_RESIDUAL_DOF
    if n_samples >= needed:
        return None
    return (
        f"{n_samples} samples for the {MODEL_PARAMETERS.get(kind, 9)} numbers of the {kind} model leave too few to "
        f"measure the noise, and so any one-sigma (at least {needed} are needed); record more while turning the sensor"
    )


def halves_apart(halves: tuple[tuple[float, float, float], tuple[float, float, float]]) -> tuple[float, float, bool]:
    """(largest axis's, root-sum-square) distance of the halves' offsets in their combined one-sigmas, and whether
    either exceeds its bound (:data:`HALVES_SIGMAS`, :data:`HALVES_RSS_SIGMAS`): the halves disagree."""
    difference, sigma = halves
    ratios = [abs(d) / max(s, 1e-300) for d, s in zip(difference, sigma, strict=True)]
    largest, rss = max(ratios), math.sqrt(sum(r * r for r in ratios))
    return largest, rss, largest > HALVES_SIGMAS or rss > HALVES_RSS_SIGMAS

_RECORD_ADVICE = (
    "record again turning the sensor slowly through all attitudes (every face pointing up and down in turn, "
    "a full tumble is best), away from magnets, motors and steel"
)


@dataclass(frozen=True)
class Evidence:
    """What the verdict is reached from (computed by :func:`magfit.diagnostics.diagnose`).

    Attributes
    ----------
    kind : {"sphere", "diag", "full"}
        The model of the returned calibration.
    residual_rms : float
        RMS sphere distance of the analysed samples under the returned calibration (fraction of the field).
    ellipsoid_rms : float or None
        The same under the best full ellipsoid, when the returned model is restricted (None: not
        computed, or no ellipsoid fits).
    coverage, observability, uncertainty
        In the frame of the returned calibration.
    known_field : tuple of (given, fitted) or None
        A field strength the user gave and the one the samples give, input units.
    consistency, goodness : optional
        The slower checks, when they ran.
    halves : tuple of (offset difference, combined one-sigma), input units, or None
        Offsets fitted on the two halves of the recording, when that ran.
    unit : str or None
        The samples' unit, for messages.
    flat : tuple of (axis words, ratio) or None
        When the raw samples lie close to a plane: the axis they hardly extend along and their spread
        along it over the largest (below 0.25). It names the cause when no ellipsoid fits.
    axis_ratio : float or None
        The fitted ellipsoid's longest semi-axis over its shortest.
    method : str or None
        The method that fitted the calibration, for messages.
    solver_problem : str or None
        The method's solver did not converge (``details["solver_problem"]``): refused, in its words.
    clipping : Clipping or None
        Rows clipped at the sensor's full scale, left out of the fit and of this evidence
        (:mod:`magfit.saturation`); None when there were none.
    comparison : ModelComparison or None
        A restricted model against the full ellipsoid on the same samples (the F test); None for a full
        model. ``uncertainty`` already covers its heading cost when it is significant.
    field_strength : float or None
        The calibration's field strength (input units), to judge offsets by.
    drifting : DriftComparison or None
        The same model with a field strength that changes along the recording; ``uncertainty`` already
        covers its heading difference when it widens it.
    mirror, offset : tuple of 3 float or None
        For a sphere pinned to a known field strength: its offset and that offset's mirror image across the
        plane the samples spread least in (:func:`mirrored_offset`), the other centre level turns allow.
    """

    kind: str
    residual_rms: float
    ellipsoid_rms: float | None
    coverage: Coverage
    observability: Observability
    uncertainty: Uncertainty
    known_field: tuple[float, float] | None = None
    consistency: Consistency | None = None
    goodness: Goodness | None = None
    halves: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
    unit: str | None = None
    flat: tuple[str, float] | None = None
    axis_ratio: float | None = None
    method: str | None = None
    field_strength: float | None = None
    solver_problem: str | None = None
    clipping: Clipping | None = None
    comparison: ModelComparison | None = None
    drifting: DriftComparison | None = None
    mirror: tuple[float, float, float] | None = None
    n_samples: int | None = None
    offset: tuple[float, float, float] | None = None


def mirrored_offset(
    offset: NDArray[np.float64], mean: NDArray[np.float64], covariance: NDArray[np.float64]
) -> tuple[float, float, float]:
    """The offset's mirror image across the plane the samples spread in least (normal n: the covariance's
    eigenvector of the smallest eigenvalue), through their mean m̄: ``V' = V + 2 ((m̄ − V)·n) n``.

    Samples of level turns lie on a circle about n. A sphere of a given radius B through that circle has its
    centre on the circle's axis at ``±√(B² − ρ²)`` from its plane (ρ the circle's radius): V and V' fit the
    samples alike, and the field strength fixes the vertical component's size, not its sign.
    """
    normal = np.linalg.eigh(covariance)[1][:, 0]
    mirror = offset + 2.0 * float((mean - offset) @ normal) * normal
    return float(mirror[0]), float(mirror[1]), float(mirror[2])


def two_solutions(offset: ArrayLike, mirror: ArrayLike, axis: str, label: str) -> str:
    """Why a sphere pinned to a known field strength leaves the offset along a turning axis open: in words."""
    shown = [", ".join(f"{v:.4g}" for v in np.asarray(point, dtype=np.float64)) for point in (offset, mirror)]
    return (
        f"the sensor only turned about {axis}, so its samples lie on a circle, and the sphere of the given field "
        f"strength passes through that circle with its centre on either side of the circle's plane: the offset is "
        f"({shown[0]}){label} or ({shown[1]}){label}, the field's component along {axis} positive or negative, and "
        "the samples fit both alike (the field strength fixes that component's size, not its sign); level turns "
        "with the field strength cannot choose: the vehicle's attitude with the reference field can (the vector "
        "or tilt method), or tilting the sensor a few tens of degrees while recording"
    )


def judge(evidence: Evidence) -> Support:
    """The verdict on one calibration from its evidence (see the module docstring for the rules)."""
    refusals = ReasonList()
    if evidence.solver_problem:
        refusals.add("solver", evidence.solver_problem)
    if evidence.n_samples is not None and (few := too_few_for_the_noise(evidence.n_samples, evidence.kind)):
        refusals.add("too_few_samples", few)
    weak = ReasonList()
    cover, observability, uncertainty = evidence.coverage, evidence.observability, evidence.uncertainty
    label = f" {evidence.unit}" if evidence.unit else ""
    best = min(evidence.residual_rms, evidence.ellipsoid_rms or math.inf)
    if best > NO_ELLIPSOID_RMS and evidence.flat is not None:
        axis, ratio = evidence.flat
        refusals.add("no_ellipsoid",
            f"the samples lie close to a plane (their spread along {axis} is {100 * ratio:.0f} % of the largest): the "
            f"sensor turned mostly about {axis}, so no ellipsoid through them is determined (the best one misses them "
            f"by {100 * best:.0f} % of the field); tilt the sensor so that both ends of {axis} face the field in turn"
        )
    elif best > NO_ELLIPSOID_RMS:
        refusals.add("no_ellipsoid",
            f"the samples lie on no ellipsoid: their distance to the best one is {100 * best:.0f} % of the field "
            "(RMS), where a sensor turned in a steady field gives a few per cent; the field or the distortion changed "
            "while recording (a magnet, motors, a moving part), the sensor barely moved, or these are not "
            "magnetometer readings"
        )
    elif evidence.residual_rms > NO_ELLIPSOID_RMS:
        refusals.add("model_inadequate",
            f"the {_fit_name(evidence)} cannot describe these samples: it leaves "
            f"{100 * evidence.residual_rms:.0f} % of the field (RMS) where a full ellipsoid leaves {100 * best:.1f} %: "
            "it misplaces the ellipsoid the samples lie on (a sphere ignores the soft iron; min/max centred on "
            "samples that do not cover every direction evenly misses the centre), and the heading would keep the "
            f"error; {_richer_would(evidence, 'would not keep it', 'the auto method would not')}"
        )
    elif best > LARGE_RESIDUAL_RMS:
        weak.add("large_residual",
            f"the residuals are large: {100 * best:.1f} % of the field (RMS) where a few per cent are usual; the field "
            "or the distortion changed while recording (motors, a magnet nearby) or the sensor is noisy: expect "
            "heading errors of a few degrees"
        )
    if evidence.axis_ratio is not None and evidence.axis_ratio > MAX_AXIS_RATIO:
        refusals.add("undetermined",
            f"the fitted ellipsoid is {evidence.axis_ratio:.0f} times longer than it is thick, where the strongest "
            "soft iron squeezes an axis about 7 times: the samples hardly reach along its short axis, and the fit "
            "scaled their noise up to the field there"
        )
    band = list(cover.unseen_axes)
    if not band and observability.turn_axis is not None:
        band.append(observability.turn_axis.lstrip("+"))
    for axis in band:
        if evidence.mirror is not None and evidence.offset is not None:
            refusals.add("single_axis", two_solutions(evidence.offset, evidence.mirror, axis, label))
            continue
        refusals.add("single_axis",
            f"the sensor only turned about {axis}: the field was never seen near +{axis} or −{axis}, so the offset "
            f"and scale along {axis} are fixed by nothing in the samples; tilt the sensor so that both ends of {axis} "
            "face the field in turn"
        )
    undetermined = [w for w in observability.weak if not w.determined]
    heading = uncertainty.heading_sigma_deg
    if undetermined and not refusals:
        parts = "; ".join(
            w.description + ("" if w.sigma is None else f" (one-sigma {100 * w.sigma:.0f} % of the field)")
            for w in undetermined
        )
        # Only the full model: the heading uncertainty of a restricted one leaves out the soft iron it cannot
        # hold (a sphere on the generic sensor tilted ±10°: ±2° stated, 12° wrong).
        relaxed = evidence.kind == "full" and heading is not None and heading <= UNDETERMINED_HEADING_DEG
        if relaxed and all(w.sigma for w in undetermined):
            weak.add("restricted_attitude",
                f"the samples do not determine {parts}: the calibration holds only near the attitudes recorded "
                f"(there the heading uncertainty at level is ±{heading:.2g}°); do not trust those numbers on their "
                "own (an offset along that axis, the field's vertical part) nor the heading at steeper tilts than "
                "recorded; tilt the sensor further while recording to determine them"
            )
        else:
            refusals.add("undetermined", f"the samples do not determine {parts}: those numbers would be noise")
    for w in observability.weak:
        if w.determined:
            effect = "" if heading is None else f"; the heading uncertainty that follows is ±{heading:.2g}°"
            weak.add("weakly_determined",
                f"{w.description} is weakly determined (one-sigma {100 * (w.sigma or 0.0):.1f} % of the field; "
                f"the samples carry {w.relative_information:.2g} of the information of a full tumble){effect}"
            )
    if evidence.known_field is not None:
        given, fitted = evidence.known_field
        ratio = fitted / given
        if abs(ratio - 1.0) > FIELD_TOLERANCE:
            refusals.add("field_mismatch",
                f"the field strength given ({given:.6g}{label}) is {ratio:.3g} times smaller than the samples show "
                f"({fitted:.6g}{label})" if ratio > 1 else
                f"the field strength given ({given:.6g}{label}) is {1 / ratio:.3g} times larger than the samples show "
                f"({fitted:.6g}{label})"
            )
            mixup = unit_mixup(ratio)
            refusals.extend_last("unit_mismatch" if mixup else "field_mismatch", (
                f": {mixup}"
                if mixup
                else ": check the value and the samples' unit (iron that scales the whole field, such as a steel "
                "plate against the sensor, does this too: then leave the field strength out)"
            ))
    comparison = evidence.comparison
    if (
        comparison is not None
        and comparison.significant
        and math.isfinite(comparison.full_heading_sigma_deg)  # an undetermined full model tells nothing here
        and all(r.code != "model_inadequate" for r in refusals)
    ):
        turn = comparison.heading_difference_deg
        times = f"{comparison.rss_ratio:.3g}" if comparison.rss_ratio < 1e4 else "over 10 000"
        words = (
            f"the {_fit_name(evidence)} leaves {times} times the squared residual of a full ellipsoid on the same "
            f"samples (F test, p = {comparison.p_value:.1g}): there is soft iron this model cannot remove"
        )
        if comparison.measured and turn > MODEL_HEADING_DEG:
            refusals.add("model_inadequate",
                f"{words}, and this fit's level heading is {turn:.2g}° from the full ellipsoid's (whose one-sigma "
                f"is ±{comparison.full_heading_sigma_deg:.2g}°); {_richer_would(evidence, 'would not leave that')}"
            )
        else:
            weak.add("model_inadequate",
                f"{words}, and this fit's level heading may be up to {comparison.heading_cost_deg:.2g}° from the "
                f"full ellipsoid's, counted in the heading uncertainty of ±{heading:.2g}°; "
                f"{_richer_would(evidence, 'would remove it')}"
            )
    elif comparison is not None and comparison.significant and all(r.code != "model_inadequate" for r in refusals):
        # The full model fits better beyond chance but the samples do not determine it: what this model misses
        # moves the heading by an amount nothing here can bound (a 10 % cap: diag ±3.1° stated, 16° wrong).
        refusals.add("model_inadequate",
            f"the {_fit_name(evidence)} leaves {comparison.rss_ratio:.3g} times the squared residual of a full "
            f"ellipsoid on the same samples (F test, p = {comparison.p_value:.1g}): there is soft iron this model "
            "cannot remove, and the samples do not determine the full ellipsoid, so what that soft iron costs the "
            "heading cannot be bounded"
        )
    elif (
        comparison is None
        and evidence.kind != "full"
        and evidence.ellipsoid_rms is not None
        and evidence.residual_rms > RESTRICTED_RESIDUAL_RATIO * evidence.ellipsoid_rms
        and LARGE_RESIDUAL_RMS / 2 < evidence.residual_rms <= NO_ELLIPSOID_RMS
    ):
        weak.add("model_inadequate",
            f"the {_fit_name(evidence)} leaves residuals of {100 * evidence.residual_rms:.1f} % of the field where a "
            f"full ellipsoid leaves {100 * evidence.ellipsoid_rms:.1f} %: there is soft iron this model cannot "
            f"remove; {_richer_would(evidence, 'would remove it', 'the ellipsoid or auto method would')}"
        )
    if cover.share < 0.5:
        weak.add("low_coverage",
            f"the samples cover only {100 * cover.share:.0f} % of the directions: the calibration is extrapolated over "
            "the rest"
        )
    goodness = evidence.goodness
    if goodness is not None and goodness.held_out is not None and goodness.held_out.std > 1.25 * goodness.fitted.std:
        weak.add("overfit",
            "the fit does much better on its own samples than on held-out ones: it is over-fitted (too many parameters "
            "for the directions covered)"
        )
    check = evidence.consistency
    field = evidence.field_strength
    shift = math.sqrt(sum(d * d for d in check.offset_difference)) / field if check is not None and field else 0.0
    adequate = evidence.ellipsoid_rms is None or evidence.residual_rms <= RESTRICTED_RESIDUAL_RATIO * best
    if adequate and check is not None and not check.consistent and (  # else its own model's ML fit runs off
        check.heading_difference_deg > BIASED_HEADING_DEG or shift > BIASED_OFFSET
    ):
        refusals.add("biased",
            f"this method is biased on these samples: its fit is {check.heading_difference_deg:.2g}° of level heading "
            f"and {100 * shift:.0f} % of the field in offset away from the maximum-likelihood fit of the same model "
            "(a method that only averages or scales the samples, or an algebraic fit of a cap of directions); the "
            "auto or ml method is not"
        )
    elif check is not None and not check.consistent and check.sigmas is not None:
        weak.add("biased",
            f"the fit is {check.sigmas:.0f} one-sigmas ({check.heading_difference_deg:.2g}° of level heading) away "
            "from the maximum-likelihood fit of the same model: this method is biased on these samples; the auto, "
            "ml or als method is not"
        )
    if evidence.halves is not None:
        difference, _ = evidence.halves
        largest, rss, apart = halves_apart(evidence.halves)
        if apart:
            shown = ", ".join(f"{d:+.3g}" for d in difference)
            counted = "" if heading is None else f" (counted in the heading uncertainty of ±{heading:.2g}°)"
            weak.add("inconsistent_halves",
                f"the two halves of the recording give offsets that differ by ({shown}){label}, "
                f"{max(largest, rss):.1f} times their one-sigma: the distortion or the field changed while recording "
                "(a sensor warming up creeps its offset, a magnet moved, motors); this fit is the recording's average, "
                f"and the sensor at either end of it is about that difference away from it{counted}; let the sensor "
                "warm up (powered a few minutes) and record again where nothing near it changes, or, where the file "
                "has a temperature column, calibrate on the rows at the working temperature"
            )
    drifting = evidence.drifting
    if drifting is not None and drifting.named:
        weak.add("field_drift",
            f"the field strength changed by up to {100 * drifting.drift:.2g} % along the recording (F test, "
            f"p = {drifting.p_value:.1g}) and this fit follows the change: its level heading is "
            f"{drifting.heading_difference_deg:.2g}° from a fit that allows for it, counted in the heading "
            f"uncertainty of ±{heading:.2g}°; record where the field is steady (the same height, away from moving "
            "iron), or use the vector method with the attitude and the reference field"
        )
    if evidence.clipping is not None:
        clipped = evidence.clipping
        (refusals if refusals else weak).add("saturated",
            f"{clipped.n_clipped} of {clipped.n_samples} samples were clipped at the sensor's full scale "
            f"({clipped.describe(evidence.unit)}) and are left out: the calibration rests on the other "
            f"{clipped.n_kept}, which miss the directions where the field plus the offset left the range; set a "
            "larger full-scale range on the magnetometer (its range or gain setting), or mount it further from the "
            "iron that pushes it out of range"
        )
    if heading is not None and heading > USELESS_BOUND_DEG and not refusals:
        weakest = "; ".join(w.description for w in observability.weak)
        refusals.add("undetermined",
            f"the level heading one-sigma of this calibration is ±{heading:.2g}°, beyond {USELESS_BOUND_DEG:g}°: a "
            "bound that wide is no calibration" + (f" (the samples hardly fix {weakest})" if weakest else "")
        )
    return Support.judged(refusals, weak, _RECORD_ADVICE)


def _richer_would(evidence: Evidence, would: str, others: str | None = None) -> str:
    """What would hold the soft iron a restricted fit misses: ``others`` (default ``"the ellipsoid or auto
    method {would}"``) for a method other than ``auto``.

    Not for ``auto``'s own fit: it is the restricted model auto chose, the full ellipsoid passed over because
    it predicted held-out stretches of the recording no better, or because the samples did not determine it
    (:mod:`magfit.methods.auto`). Advising auto there is circular. Over most directions (coverage of half the
    sphere or more) the full ellipsoid fitted alone (``ml``, judged on its own) is what holds the distortion;
    over a few, only more tilt or a reference field determines it.
    """
    if evidence.method != "auto":
        return others if others is not None else f"the ellipsoid or auto method {would}"
    if evidence.coverage.share >= 0.5:
        return (
            f"auto kept the {evidence.kind} model because the full ellipsoid predicted held-out stretches of the "
            "recording no better (what it adds may change along the recording: motors, a moving part); fitted "
            f"alone ({option('method', 'ml')}, judged on its own) the full ellipsoid {would}"
        )
    return (
        f"auto kept the {evidence.kind} model because the samples do not determine the full ellipsoid or it "
        "predicted held-out stretches of the recording no better; more tilt while recording, or a reference field "
        f"({option('method', 'vector')} with the attitude), would determine it"
    )


def _fit_name(evidence: Evidence) -> str:
    """``"sphere model"``, or ``"minmax fit"`` when the method is not named after its model."""
    if evidence.method and evidence.method != evidence.kind:
        return f"{evidence.method} fit"
    return f"{evidence.kind} model"


#: Ratios of common unit mix-ups: (factor, what it usually is).
_MIXUPS = (
    (10.0, "a factor of 10: µT against mG (1 µT = 10 mG)"),
    (100.0, "a factor of 100: gauss against µT (1 G = 100 µT), or mG against nT"),
    (1000.0, "a factor of 1000: µT against nT (1 µT = 1000 nT), or gauss against mG"),
    (1e4, "a factor of 10 000: tesla against gauss (1 T = 10 000 G)"),
    (1e5, "a factor of 100 000: gauss against nT (1 G = 100 000 nT)"),
    (1e6, "a factor of a million: tesla against µT"),
)


def unit_mixup(ratio: float) -> str | None:
    """Words for a ratio between two field strengths that looks like a unit mix-up (within 20 %), or None."""
    if not ratio > 0:
        return None
    size = max(ratio, 1.0 / ratio)
    for factor, words in _MIXUPS:
        if abs(math.log(size / factor)) < math.log(1.2):
            return "likely a unit mix-up, " + words
    return None
