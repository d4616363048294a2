"""Automatic model choice: sphere, axis-aligned or full ellipsoid, robust when outliers are present.

The three models are nested (sphere ⊂ diag ⊂ full: 4, 6 and 9 parameters besides the rotation the
data cannot see). ``auto`` returns the simplest model the samples determine that no richer one predicts
clearly better on stretches of the recording it did not see (docs/diagnostics.md, "auto"):

1. Each model is fitted and refined to its maximum-likelihood fit (Levenberg-Marquardt on the first-order
   distances ``d`` of :mod:`magfit.geometry.frame`, on a regular stride of at most :data:`CHOICE_ROWS`
   samples). An optimum flattened onto the samples (they lie in a plane within the noise) is left out.
2. A simpler model leaving more than :data:`INADEQUATE_RATIO` times a richer one's RMS distance (and more
   than :data:`INADEQUATE_RMS` of the field) cannot stand in for it (the soft iron would stay in the
   heading). The others are judged by the support verdict (:mod:`magfit.diagnostics.verdict`) at their
   optimum: models with an undetermined direction, a band or a cone of directions are passed over.
3. Among the determined models, a richer one replaces a simpler one only when it predicts
   :data:`BLOCKS` contiguous held-out blocks of the recording better by more than one standard error of
   the paired differences (and :data:`MIN_GAIN`). The BIC, ``n ln(RSS / n) + k ln n`` (Schwarz, Ann.
   Statist. 6, 1978), is reported but does not choose: it counts every sample as independent evidence, so
   on long logs it prefers the richer model whenever it follows effects no calibration holds (a drifting
   field, a vehicle's slowly changing fields) with its weakly determined parameters.
4. Where a richer model is not determined (restricted attitudes: a vehicle), every richer model that predicts
   the held-out blocks as well or better shows a distortion the chosen model may leave out. Its heading error
   (the level-heading difference of the two models plus the richer one's heading one-sigma) joins the
   chosen model's heading one-sigma (``Calibration.auto.omitted``, added by this method's registry
   entry, :class:`~magfit.methods.registry.Judging`), named as a weakness. When the richer model clearly
   wins (:data:`WITNESS_GAIN`) and that bound passes :data:`PREFERRED_BOUND_DEG`, a full model the verdict
   returns weak is taken instead; beyond :data:`USELESS_BOUND_DEG` without one, auto refuses
   (:class:`UndeterminedChoice`, which carries the model the choice ranks best for a forced fit).

The calibration returned is the chosen model's maximum-likelihood fit on a stride of at most
:data:`REFIT_ROWS` samples (its stated uncertainty is for the rows read): for the full ellipsoid the ``ml``
method's fit (exact orthogonal distances, corrected for the σ²-bias of curved surfaces); for the sphere and
diag models, the first-order fit of the model choice.

Outliers: when the plain algebraic fit leaves far samples, a robust algebraic fit screens a stride of at
most :data:`SCREEN_ROWS` samples; when more than 0.2 % of them (and at least 5) lie beyond 6 robust
standard deviations, every candidate is fitted robustly and the choice uses the common inliers.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._validation import check_choice
from ..calibration import Calibration
from ..diagnostics import DEFAULT_INCLINATION_DEG, diagnose
from ..diagnostics.uncertainty import drift_allowing_fit, level_heading_difference_deg
from ..diagnostics.verdict import USELESS_BOUND_DEG
from ..errors import CalibrationError, MagfitError
from ..evaluate import unchecked_sphere_distances
from ..facts import AutoChoice
from ..findings import Diagnostics, Reason, Support, said_once
from ..geometry.quadric import check_field_strength, pin_field_strength
from ..outliers import DEFAULT_THRESHOLD
from ..remedy import option
from ..saturation import find_clipped
from ..statistics import Statistics
from .core import estimate, first_order_refit
from .registry import METHODS, FitInput, Judging, Refit, Undetermined, register
from .robust import fit_model, rejected_runs, resolve_model, robust_scale

__all__ = ["CANDIDATES", "UndeterminedChoice", "fit_auto", "fit_chosen"]

#: Candidate models, simplest first.
CANDIDATES = ("sphere", "diag", "full")
N_PARAMETERS = {"sphere": 4, "diag": 6, "full": 9}
OUTLIER_MODES = ("detect", "reject", "keep")
#: An optimum with a semi-axis shorter than this many RMS residual distances, along which the samples
#: spread less than FLAT_SPREAD times their widest spread and less than FLAT_NOISE_SPREAD residuals, is
#: flattened onto the samples. The last condition keeps a real, very eccentric ellipsoid seen through
#: heavy noise (the paper's steel case at 10 % noise: shortest semi-axis 7 residuals, spread along it 0.15
#: of the widest but 4.2 residuals), where samples in a plane spread about one residual across it.
FLAT_SEMI_AXIS = 10.0
FLAT_SPREAD = 0.25
FLAT_NOISE_SPREAD = 2.5
#: A sample beyond this many robust standard deviations counts as an outlier when screening.
_SCREEN_SIGMAS = 6.0
#: A simpler model whose RMS distance is this many times a richer model's cannot stand in for it.
INADEQUATE_RATIO = 2.0
INADEQUATE_RMS = 0.05
#: A model whose Σd² starts this many times the full ellipsoid's (its algebraic fit) stops after
#: HOPELESS_ITERATIONS steps: it would need a 16 times smaller Σd² to become adequate (INADEQUATE_RATIO²).
HOPELESS = 4.0 * INADEQUATE_RATIO**4
HOPELESS_ITERATIONS = 10
#: Contiguous blocks of the recording held out in turn to compare the models.
BLOCKS = 10
#: Rows (a regular stride of the recording) for the outlier screen, the models' optima and the held-out
#: blocks: enough for the 4-9 parameters, few enough to refit live several times a second.
SCREEN_ROWS = 3_000
CHOICE_ROWS = 2_000
BLOCK_ROWS = 2_000
#: Refits that only score held-out samples stop at this relative change of the cost.
SCORE_TOLERANCE = 1e-4
#: ... or after this many iterations: they start at the optimum on all the samples, a small step away.
SCORE_ITERATIONS = 5
#: The optima the model choice compares stop at this relative change of the cost.
CHOICE_TOLERANCE = 1e-5
#: A richer model must predict held-out blocks better by at least this share of the simpler one's distance.
MIN_GAIN = 0.01
#: A richer model that predicts held-out blocks better by this share (and twice the block-to-block standard
#: error) shows that the chosen model clearly misses a distortion: when the chosen model's heading bound (its
#: one-sigma with the heading error of that distortion) passes PREFERRED_BOUND_DEG, a full model the verdict
#: returns (weak: it pins the heading near the attitudes recorded) is taken instead of it.
WITNESS_GAIN = 0.15
PREFERRED_BOUND_DEG = 5.0
#: Otherwise the chosen model is returned, weak, its heading bound stated; beyond USELESS_BOUND_DEG (the
#: verdict's) auto refuses: no compass.


class UndeterminedChoice(Undetermined):
    """``auto`` refused: no model the samples determine describes them within a useful heading bound.

    ``calibration`` is what the unforced choice ranks best (the richest model the samples determine), which
    :func:`magfit.fit` returns with this refusal when ``allow_undetermined=True``.
    """


def _chosen_refit(calibration: Calibration, options: Any) -> Refit:
    """The diagnostics' refit of an ``auto`` calibration: its chosen model's first-order fit, from it."""
    if calibration.auto is None:  # a calibration saved without its choice: the model it has
        return _model_refit(calibration, options)
    chosen, known = calibration.auto.model, options.get("field_strength")
    return lambda samples: first_order_refit(chosen, calibration, samples, field_strength=known)


def _model_refit(calibration: Calibration, options: Any) -> Refit:
    from ..diagnostics import model_kind

    kind, known = model_kind(calibration), options.get("field_strength")
    return lambda samples: first_order_refit(kind, calibration, samples, field_strength=known)


def omitted_heading_deg(calibration: Calibration) -> float:
    """The heading error (degrees) of the distortion the chosen model leaves out, 0 when none."""
    return calibration.auto.omitted_heading_deg if calibration.auto is not None else 0.0


def omitted_offset(calibration: Calibration) -> tuple[float, float, float] | None:
    """The offset error (input units, per axis) of the distortion the chosen model leaves out, None when none.

    It joins the offset one-sigma as :func:`omitted_heading_deg` joins the heading one-sigma: without it, a
    sphere chosen on a vehicle's tilts stated its offset 10-40 times closer than it was (the campaign's tilt
    cones, flights and the paper's smartphone tilted ±30°; benchmarks/results/auto_coverage.md).
    """
    omitted = calibration.auto.omitted if calibration.auto is not None else None
    value = (omitted or {}).get("offset")
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        return None
    effect = tuple(float(v) for v in value)
    return (effect[0], effect[1], effect[2]) if all(math.isfinite(v) and v >= 0.0 for v in effect) else None


def omitted_weakness(calibration: Calibration, report: Diagnostics) -> tuple[Reason, ...]:
    """The weakness naming the distortion the chosen model leaves out, with the heading error it causes."""
    heading = omitted_heading_deg(calibration)
    if not heading or calibration.auto is None or calibration.auto.omitted is None:
        return ()
    omitted, model = calibration.auto.omitted, calibration.auto.model
    stated = report.uncertainty.heading_sigma_deg if report.uncertainty is not None else None
    total = "" if stated is None else f"; the heading one-sigma stated includes it: ±{stated:.2g}°"
    offset = omitted_offset(calibration)
    if offset is not None:
        unit = f" {calibration.unit}" if calibration.unit else " (input units)"
        total += f"; it can move the offset by up to {max(offset):.2g}{unit}, in the offset one-sigma stated too"
    difference = omitted.get("heading_difference_deg")
    witness_sigma = omitted.get("witness_heading_sigma_deg")
    parts = (
        f"their level headings differ by {difference:.2g}° (RMS) and the {omitted.get('model')} model's own heading "
        f"one-sigma is ±{witness_sigma:.2g}°: "
        if isinstance(difference, (int, float)) and isinstance(witness_sigma, (int, float))
        else ""
    )
    return (Reason(
        f"the {model} model may leave out a distortion the samples show but do not determine (the "
        f"{omitted.get('model')} model, fitted to the same samples, predicts held-out stretches of the recording as "
        f"well or better); {parts}the heading error it can cause is ±{heading:.2g}°{total}; a reference field "
        f"({option('method', 'vector')} with the attitude) or more tilt while recording would determine it",
        "model_inadequate",
    ),)  # fmt: skip


#: The most samples auto's final fit (:func:`refine_chosen`, the maximum-likelihood refit) reads: a regular
#: stride of its samples beyond; its model choice reads fewer. The diagnostics read the same stride, so the
#: one-sigma stated is that of a fit to these rows (it shrinks as 1/√rows where the noise dominates): the
#: bound trades that one-sigma on long recordings against the refit's time, linear in the rows (four
#: evaluations of the exact orthogonal distances). It also bounds the rows ``magfit calibrate`` streams for
#: ``auto`` (:attr:`~magfit.methods.registry.MethodSpec.fit_rows`).
REFIT_ROWS = 50_000


@register(
    "auto",
    min_samples=12,
    data="samples",
    summary="the simplest of sphere, diag and full ellipsoid that the samples determine and that held-out "
    "stretches of the recording do not reject; robust when outliers are found",
    # It returns its chosen model's maximum-likelihood fit: the comparison with that fit is moot.
    judging=Judging(
        refit=_chosen_refit,
        model_error_deg=omitted_heading_deg,
        model_error_offset=omitted_offset,
        weaknesses=omitted_weakness,
        compare_ml=False,
    ),
    fit_rows=REFIT_ROWS,
)
def fit_auto(data: FitInput, *, outliers: str = "detect", field_strength: float | None = None) -> Calibration:
    """Fit the simplest model the samples support, robustly when they hold outliers.

    Parameters
    ----------
    outliers : {"detect", "reject", "keep"}
        ``"detect"``: screen for outliers and fit robustly when they are found; ``"reject"``: always fit
        robustly; ``"keep"``: never.
    field_strength : float, optional
        Known magnitude of the local field (e.g. from the World Magnetic Model), input units: the chosen
        fit's matrix is scaled so that corrected samples have this magnitude (see ``pin_field_strength``).

    Returns
    -------
    Calibration
        ``method="auto"``; ``details``: ``chosen`` (e.g. ``"full"`` or ``"robust diag"``),
        ``chosen_model``, ``method_used`` (the registered method whose fit started the maximum-likelihood
        refinement that is returned), ``reason`` (one sentence),
        ``criterion`` (name, value per candidate, RSS and parameter count), ``weak`` (descriptions of the
        weakly determined directions of the chosen model), ``failed`` (candidates that could not be
        fitted, with the reason) and, when fitted robustly, ``n_rejected`` and ``rejected``.
    """
    check_choice("outliers", outliers, OUTLIER_MODES)
    known_field = check_field_strength(field_strength)
    samples = data.require_samples("auto")
    n = samples.shape[0]
    robust, inliers, screen_note = _screen(samples, outliers)
    # The candidates share one search for clipped rows (the fit's own, when its statistics' pass made it): each
    # would otherwise read every sample again (methods.core.without_clipped), a pass over a long log per model.
    clipping = data.clipping if data.clipping is not None and data.clipping.n_samples == n else find_clipped(samples)
    shared = FitInput(data.statistics, samples, clipping)
    failed: dict[str, str] = {}
    fits: dict[str, Calibration] = {}
    for model in CANDIDATES:
        try:
            fits[model] = _fit_candidate(model, shared, robust)
        except MagfitError as error:
            failed[model] = str(error)
    if not fits:
        raise _refusal("no model could be fitted to these samples", samples, failed)
    if robust:  # the common inliers: kept by every robust candidate
        for calibration in fits.values():
            inliers &= _kept(calibration, n)
    kept = samples if inliers.all() else samples[inliers]  # no copy of a long log without outliers
    rss, optima, degenerate = _optimal_rss(fits, kept)
    failed.update(degenerate)
    if not rss:
        raise _refusal("no model fits these samples", kept, failed)
    m = kept.shape[0]
    bic = {
        model: m * math.log(max(value, 1e-300) / m) + N_PARAMETERS[model] * math.log(m) for model, value in rss.items()
    }
    ranked = sorted(bic, key=bic.__getitem__)
    best = ranked[0]
    inadequate = _inadequate(rss, m)  # first: no need to judge a model that cannot stand in for a richer one
    reports = {model: _candidate_report(optima[model], kept) for model in optima if model not in inadequate}
    verdicts = {
        model: Support("refused", (Reason(inadequate[model], "model_inadequate"),), (), "")
        if model in inadequate
        else _support(reports[model])
        for model in CANDIDATES
        if model in optima
    }
    # A full model with a combination the samples do not determine is returned (weak) only when it pins the
    # heading near the attitudes recorded (the verdict's rule); auto takes it only as the witness below, when
    # every determined model misses a distortion: chosen on held-out blocks, its undetermined scale along z
    # follows a drifting field (level flight ±15°, ±0.5 % drift: 3.6° of heading against the sphere's 0.9°).
    determined = [
        model
        for model in CANDIDATES
        if model in verdicts and verdicts[model].verdict != "refused" and not _undetermined(reports[model])
    ]
    returned_weak = [
        m for m in CANDIDATES if m in verdicts and verdicts[m].verdict != "refused" and m not in determined
    ]
    if not determined and returned_weak:  # e.g. the steel case tilted ±20°: the sphere inadequate, the full weak
        determined = returned_weak[-1:]
    if not determined:
        message = (
            "the samples determine no calibration model: "
            + said_once([(f"the {model} model", model, verdicts[model].refusals) for model in verdicts])
            + "; record again turning the sensor through more attitudes (a full tumble is best)"
            + _on_a_vehicle()
        )
        # Forced (allow_undetermined), the simplest model that can describe the samples: the fewest numbers
        # the samples fail to fix.
        simplest = next((model for model in CANDIDATES if model in optima and model not in inadequate), None)
        if simplest is None:
            undetermined = CalibrationError(message, codes=("undetermined",), remedy=VEHICLE_REMEDY)
        else:
            bare = _bare(simplest, optima[simplest], n, message, known_field)
            undetermined = UndeterminedChoice(message, bare, "undetermined")
            undetermined.remedy = VEHICLE_REMEDY
        undetermined.general_advice = _on_a_vehicle()
        raise undetermined
    # Richer models the samples do not determine still witness what the chosen one misses (below).
    witnesses = [
        model
        for model in CANDIDATES[CANDIDATES.index(determined[-1]) + 1 :]
        if model in optima and model not in determined and model not in inadequate
    ]
    compared = determined + witnesses
    held_out = _blocked_scores(kept, optima, compared) if len(compared) > 1 else {}  # one left: no choice
    chosen, steps = _choose(determined, held_out)
    # Where the samples leave a richer model undetermined (restricted attitudes), every richer model than the
    # one chosen, determined or not, may show a distortion it leaves out; on a full tumble none does.
    richer = [model for model in CANDIDATES[CANDIDATES.index(chosen) + 1 :] if model in held_out]
    missed = _missed(chosen, richer, held_out) if witnesses else None
    # Samples in a plane (level turns) flatten every richer ellipsoid, so none witnesses; the ellipse they
    # trace in their plane is determined, and the soft iron it shows is in the chosen model's headings.
    flattened = [model for model in CANDIDATES[CANDIDATES.index(chosen) + 1 :] if model in degenerate]
    planar = _planar_witness(optima[chosen], kept) if missed is None and flattened else None
    omitted: dict[str, Any] | None = None
    refusal: str | None = None
    if missed is not None or planar is not None:
        if missed is not None:
            witness, words, clear = missed
            witness_fit = optima[witness]
        else:
            assert planar is not None
            witness, words, clear = "planar ellipse", planar[1], False
            witness_fit = planar[0]
        # The heading error the left-out distortion can cause: how far the chosen model's level headings are
        # from the richer model's (which holds the distortion), plus that model's own heading one-sigma (the
        # difference is known no better): on the benchmark's aircraft the difference alone fell short of the
        # sphere's error on 5 of 20 trials, with the richer model's one-sigma on 1.
        # The witness fitted with a field strength that may drift along the recording: a drift its soft iron
        # followed is no distortion the chosen model leaves out (its one-sigma counts what the drift moved).
        if missed is not None:
            witness_fit = drift_allowing_fit(kept, witness, witness_fit) or witness_fit
        difference = level_heading_difference_deg(optima[chosen], witness_fit, DEFAULT_INCLINATION_DEG)
        witness_sigma = _heading_sigma(reports.get(witness))
        effect = difference + (witness_sigma or 0.0)
        sigma = _heading_sigma(reports.get(chosen))
        bound = math.hypot(sigma or 0.0, effect)
        standing = [w for w in witnesses if verdicts[w].verdict != "refused"]  # returned by the verdict, weak
        if clear and bound > PREFERRED_BOUND_DEG and standing and _holds(optima[standing[-1]], kept, standing[-1]):
            steps.append(
                f"the {chosen} model {words}, a distortion worth ±{effect:.2g}° of heading; the "
                f"{standing[-1]} model is returned: it pins the heading near the attitudes recorded"
            )
            chosen = standing[-1]
        else:
            # Returned or (beyond the useless bound) refused, the distortion left out is in the heading one-sigma
            # the calibration states: a forced fit states the bound its refusal gives, not its model's own.
            omitted = {
                "model": witness,
                "heading_difference_deg": difference,
                "witness_heading_sigma_deg": witness_sigma,
                "heading_deg": effect,
                # The offset it can move, per axis and in the same way: how far the richer model's offset is
                # from the chosen one's, plus its own one-sigma (the campaign's tilt cones: a sphere's offset
                # 40 times its one-sigma from the truth, soft iron of ±15 % left out).
                "offset": _offset_effect(optima[chosen], witness_fit, reports.get(witness)),
                "gain": words,
            }
        if omitted is not None and bound <= USELESS_BOUND_DEG:
            steps.append(
                f"the {chosen} model {words}: it is returned (the samples determine no richer model that describes "
                "them better on every stretch), the heading error of the distortion it leaves out in its stated "
                "heading one-sigma (see the weaknesses)"
            )
        elif omitted is not None:
            # Refused; a forced fit still gets the model the unforced choice ranks best, with this refusal.
            why = "; ".join(verdicts[w].refusals[0] for w in witnesses if verdicts[w].refusals)
            refusal = (
                f"the samples determine no model that describes them within a useful heading bound: the {chosen} "
                f"model, the richest they determine, {words}, and the heading error that distortion can cause "
                f"(±{effect:.2g}°; with the {chosen} model's own one-sigma, beyond {USELESS_BOUND_DEG:g}°) leaves no "
                "usable calibration; that model is not determined" + (f" ({why})" if why else "") + "; record "
                "again turning the sensor through more attitudes (tilt it further: a full tumble is best)"
                + _on_a_vehicle()
            )
    calibration = optima[chosen]
    if chosen == "full" or kept.shape[0] > 20_000:  # the optimum came from a stride of 20 000, or ml is due
        calibration = refine_chosen(chosen, calibration, kept, shared if kept is samples else None)
    prefix = "robust " if robust else ""
    passed_over = [
        f"the {model} model was passed over: {'; '.join(verdicts[model].refusals)}"
        for model in verdicts
        if model not in determined and verdicts[model].refusals
    ]
    opening = (
        "the simplest the samples determine that no richer one predicts held-out stretches of the recording "
        "clearly better"
        if chosen in determined and not _undetermined(reports[chosen])
        else "not determined in every direction, returned because no model the samples determine describes them "
        "(see below)"
    )
    reason = _reason(best, chosen, opening, bic, steps, passed_over, failed, screen_note)
    choice = AutoChoice(
        model=chosen,
        chosen=prefix + chosen,
        method_used=("robust/" if robust else "") + resolve_model(chosen)[0],
        reason=reason,
        omitted=omitted,
    )
    details: dict[str, Any] = {
        "criterion": {
            "name": "BIC",
            "values": {model: bic.get(model) for model in CANDIDATES},
            "rss": {model: rss.get(model) for model in CANDIDATES},
            "parameters": dict(N_PARAMETERS),
            "n": m,
        },
        "held_out": {
            "name": f"mean squared distance on {BLOCKS} contiguous blocks of the recording, each held out in turn",
            "values": {m: [float(v) for v in held_out[m]] if m in held_out else None for m in CANDIDATES},
            "determined": determined,
        },
        "failed": failed,
        "outliers": outliers,
        "robust": robust,
    }
    rejected = rejected_runs(np.flatnonzero(~inliers), DEFAULT_THRESHOLD) if robust else None
    chosen_fit = Calibration(
        method="auto",
        offset=calibration.offset,
        matrix=calibration.matrix,
        field_strength=calibration.field_strength,
        n_samples=n,
        details=details,
        model=chosen,  # type: ignore[arg-type]
        rejected=rejected,
        auto=choice,
    )
    chosen_fit = pin_field_strength(chosen_fit, known_field)
    if refusal is not None:
        refused = UndeterminedChoice(refusal, chosen_fit)
        refused.remedy, refused.general_advice = VEHICLE_REMEDY, _on_a_vehicle()
        raise refused
    return chosen_fit


#: The refusals of restricted attitudes suggest, as data, the method that works best where the attitude is
#: logged (a vehicle: it cannot be tumbled); their words name the others (:func:`_on_a_vehicle`).
VEHICLE_REMEDY = (("method", "vector"),)


def _on_a_vehicle() -> str:
    """What works where the sensor cannot be tumbled (a vehicle), in the audience's words.

    Magnitude alone cannot fix a distortion along directions the field never took; what the vehicle knows
    can: its attitude with the reference field (``vector``), its gyroscope's rates (``gyro``), or the field
    strength known at the place, which pins the sphere's scale so that its offsets are all that is fitted.
    """
    return (
        f"; on a vehicle, what it knows determines the calibration: its attitude with the reference field "
        f"({option('method', 'vector')}), its gyroscope ({option('method', 'gyro')}), or the field strength known "
        f"at the place ({option('method', 'sphere')} given that field strength)"
    )


def _bare(model: str, optimum: Calibration, n: int, reason: str, known_field: float | None) -> Calibration:
    """``model``'s optimum as ``auto``'s calibration when no model is determined (returned only when forced)."""
    choice = AutoChoice(model=model, chosen=model, method_used=resolve_model(model)[0], reason=reason)
    bare = Calibration("auto", optimum.offset, optimum.matrix, optimum.field_strength, n_samples=n,
                       model=model, auto=choice)  # type: ignore[arg-type]  # fmt: skip
    return pin_field_strength(bare, known_field)


def _optimal_rss(
    fits: dict[str, Calibration], kept: NDArray[np.float64]
) -> tuple[dict[str, float], dict[str, Calibration], dict[str, str]]:
    """Σ d² at each model's maximum-likelihood optimum over all kept samples, and the optima themselves.

    Each model is scored at the minimum of the sum of squared (first-order) distances of the samples to
    its ellipsoid (its maximised likelihood under isotropic Gaussian noise), reached from the better of the
    model's own fit and the simpler model's optimum (so a richer model never scores worse than a simpler
    one it contains). The sum runs on a regular stride of at most :data:`CHOICE_ROWS` samples, scaled to
    all of them; the sums are in units of the data's radius squared (only ratios matter). The optima
    (when real ellipsoids) are the calibrations ``auto`` returns and the references at which the verdict
    judges each model. A model whose optimum has a semi-axis shorter than
    :data:`FLAT_SEMI_AXIS` residual distances is left out (third return value: why).
    """
    from ..geometry.frame import Frame, calibration_from_parameters, maximum_likelihood, parameters, unit_map

    rows = _stride(kept, CHOICE_ROWS)
    scale = kept.shape[0] / rows.shape[0]
    frame = Frame.of(rows)
    z = frame.normalise(rows)
    rss: dict[str, float] = {}
    optima: dict[str, Calibration] = {}
    degenerate: dict[str, str] = {}
    previous: tuple[str, NDArray[np.float64]] | None = None
    widest = float(np.sqrt(np.linalg.eigvalsh(np.cov(z.T))[-1]))  # the samples' largest principal spread
    richest = _cost(parameters(fits["full"], "full", frame), z, "full") if "full" in fits else math.inf
    for model in CANDIDATES:  # simplest first: each richer model also starts from the simpler optimum
        if model not in fits:
            continue
        starts = [parameters(fits[model], model, frame)]
        if previous is not None:
            starts.append(_embed(previous[1], previous[0], model))
        start = min(starts, key=lambda p: _cost(p, z, model))
        # A model that starts HOPELESS times above the full ellipsoid's algebraic fit in Σd² cannot come within
        # INADEQUATE_RATIO of it: its Gauss-Newton steps crawl (large residuals), 80 of them for a sphere on the
        # steel case (a third of auto's time), for a Σd² still 300 times the full one's. A few steps do.
        hopeless = _cost(start, z, model) > HOPELESS * richest
        # From the better start only: the richer model still never scores worse than the simpler optimum.
        value, optimum = maximum_likelihood(
            z, model, [start], cost_tolerance=CHOICE_TOLERANCE, max_iterations=HOPELESS_ITERATIONS if hopeless else None
        )
        eigenvalues, axes = np.linalg.eigh(unit_map(optimum, model))
        strongest = int(np.argmax(np.abs(eigenvalues)))
        shortest = 1.0 / float(abs(eigenvalues[strongest]))
        rms = math.sqrt(value / z.shape[0])
        # Only the two together mark a flattened fit: a short axis of a few residuals, along which the samples
        # barely spread compared with their widest direction (they lie in a plane). Noise alone (a short
        # axis of a few residuals on a full tumble with 10 % noise) is not flatness.
        spread = float(np.std(z @ axes[:, strongest]))
        if shortest < FLAT_SEMI_AXIS * rms and spread < min(FLAT_SPREAD * widest, FLAT_NOISE_SPREAD * rms):
            # An ellipsoid flattened onto the samples: they lie in a plane within the noise, and the fit
            # turned the noise across that plane into the ellipsoid's thickness.
            degenerate[model] = (
                f"its best fit is flattened onto the samples (shortest semi-axis {shortest / rms:.1f} times the "
                "residual distance): they lie in a plane within the noise"
            )
            continue
        rss[model] = scale * value
        previous = (model, optimum)
        try:
            optima[model] = calibration_from_parameters(optimum, model, frame, model)
        except MagfitError:
            optima[model] = fits[model]
    return rss, optima, degenerate


def _cost(p: NDArray[np.float64], z: NDArray[np.float64], model: str) -> float:
    """Σ d² at p (inf where the distances are not finite)."""
    from ..geometry.frame import distances

    with np.errstate(all="ignore"):
        value = float(np.sum(distances(p, z, model) ** 2))
    return value if np.isfinite(value) else math.inf


def refine_chosen(
    model: str, start: Calibration, samples: NDArray[np.float64], given: FitInput | None = None
) -> Calibration:
    """What ``auto`` returns for ``model``, fitted to (a stride of at most :data:`REFIT_ROWS` of) ``samples``.

    The full ellipsoid: the ``ml`` fit (orthogonal distances with the mean-curvature bias correction);
    the first-order maximum-likelihood fit of :func:`_optimal_rss` grows the ellipsoid by about σ²/B and
    skews it at high noise (measured at σ = 10 % of the field, N = 100 000: 1.45 % error in the
    ellipsoid matrix against 0.25 % for ``ml``). Sphere and diag, or when ``ml`` fails: that first-order
    fit, from ``start``. ``given``: ``samples`` with their statistics and clipped rows, when the caller has
    them (used when the stride takes every sample: two passes over them saved).
    """
    from ..geometry.frame import Frame, calibration_from_parameters, maximum_likelihood, parameters

    step = max(1, math.ceil(samples.shape[0] / REFIT_ROWS))
    rows = samples[::step]  # at most REFIT_ROWS, the rows of sampling.thin (a view: no copy)
    if model == "full" and "ml" in METHODS:
        try:
            data = given if step == 1 and given is not None else FitInput(Statistics.from_samples(rows), rows)
            fitted = estimate(data, "ml")
            if fitted.solver is None or fitted.solver.converged is not False:
                return fitted
        except (MagfitError, np.linalg.LinAlgError):
            pass  # e.g. no ellipsoid to start from, or too few directions: the first-order fit below
    frame = Frame.of(rows)
    _, optimum = maximum_likelihood(frame.normalise(rows), model, [parameters(start, model, frame)])
    return calibration_from_parameters(optimum, model, frame, model)


def _stride(samples: NDArray[np.float64], rows: int) -> NDArray[np.float64]:
    """At most ``rows`` samples at a regular stride, in recording order (a view, no copy)."""
    return samples[:: max(1, math.ceil(samples.shape[0] / rows))]


#: What the diagnostics refit for an ``auto`` calibration (held-out folds, halves): the chosen model,
#: fitted as the model choice fits it, from the returned calibration (a few iterations).
refit_first_order = first_order_refit


def fit_chosen(model: str, samples: NDArray[np.float64], *, field_strength: float | None = None) -> Calibration:
    """What ``auto`` returns once it has chosen ``model``: the model's fit refined to maximum likelihood.

    ``field_strength``: the known field the user gave ``auto`` (the matrix is scaled to it).
    """
    refined = refine_chosen(model, fit_model(model, samples), samples)
    return pin_field_strength(refined, check_field_strength(field_strength))


def _embed(p: NDArray[np.float64], kind: str, target: str) -> NDArray[np.float64]:
    """The parameters of a simpler model as parameters of a richer one (the same ellipsoid)."""
    offset = p[:3]
    scales = np.full(3, p[3]) if kind == "sphere" else p[3:6]
    if target == "diag":
        return np.concatenate([offset, scales])
    cross = np.zeros(3) if kind != "full" else p[6:9]
    return np.concatenate([offset, scales, cross])


def _screen(samples: NDArray[np.float64], mode: str) -> tuple[bool, NDArray[np.bool_], str]:
    """Whether to fit robustly, the inliers known so far, and a sentence on what was found.

    The screen is a robust algebraic ellipsoid fit (sphere when that fails) on a regular stride of at most
    3 000 samples: enough to see 0.2 % of outliers, cheap on long logs; it runs only when the plain fit
    leaves far samples (:func:`_far_from_plain_fit`). The robust candidates then find their own inliers
    among all samples.
    """

    everything = np.ones(samples.shape[0], dtype=bool)
    if mode == "keep":
        return False, everything, ""
    rows = _stride(samples, SCREEN_ROWS)
    threshold = max(5, math.ceil(2e-3 * rows.shape[0]))
    if mode == "detect" and _far_from_plain_fit(rows) < threshold:
        return False, everything, ""  # not even the plain fit, which spikes pull, leaves far samples
    screen = None
    for model in ("ellipsoid", "sphere"):  # the algebraic fit: enough to see far samples, and cheap
        try:
            screen = estimate(FitInput(Statistics.from_samples(rows), rows), "robust", {"model": model})
            break
        except MagfitError:
            continue
    if screen is None:
        return mode == "reject", everything, ""
    residuals = unchecked_sphere_distances(screen, rows)
    centre, sigma = robust_scale(residuals)
    far = int(np.sum(np.abs(residuals - centre) > _SCREEN_SIGMAS * max(sigma, 1e-12)))
    found = far >= threshold
    if mode == "reject" or found:
        note = (
            f"{far} of {rows.shape[0]} screened samples lie beyond {_SCREEN_SIGMAS:.0f} robust standard deviations "
            "of the fitted ellipsoid (spikes, saturation or a magnet): every model was fitted robustly"
            if found
            else "robust fitting was requested"
        )
        return True, everything, note
    return False, everything, ""


def _far_from_plain_fit(rows: NDArray[np.float64]) -> int:
    """Samples beyond 4 robust standard deviations of the plain algebraic ellipsoid (all, if there is none).

    A quick first look: outliers pull the plain fit but still lie far from it, so a recording with fewer
    such samples than the screen's count has nothing the robust screen would find (it uses 6 deviations
    of a fit they cannot pull).
    """
    from ..geometry.frame import Frame, distances, parameters
    from ..geometry.quadric import algebraic_ellipsoid, calibration_from_ellipsoid

    found = algebraic_ellipsoid(Statistics.from_samples(rows))
    if isinstance(found, str):
        return rows.shape[0]
    frame = Frame.of(rows)
    # Distances in the sample space, where the noise is isotropic: on an eccentric ellipsoid the corrected
    # residual's noise differs from axis to axis, and its tails would look like outliers.
    p = parameters(calibration_from_ellipsoid("screen", *found), "full", frame)
    with np.errstate(all="ignore"):
        residuals = distances(p, frame.normalise(rows), "full")
    centre, sigma = robust_scale(residuals)
    return int(np.sum(np.abs(residuals - centre) > 4.0 * max(sigma, 1e-12)))


def _refusal(opening: str, samples: NDArray[np.float64], failed: dict[str, str]) -> CalibrationError:
    """Why no model is left: ``opening``, what the samples' shape says, and each model's reason."""
    reasons = said_once([(model, model, (reason,)) for model, reason in failed.items()])
    return CalibrationError(opening + _flatness(samples) + ": " + reasons)


def _kept(calibration: Calibration, n: int) -> NDArray[np.bool_]:
    mask = np.ones(n, dtype=bool)
    for start, stop in calibration.rejected.runs if calibration.rejected is not None else ():
        mask[start:stop] = False
    return mask


def _fit_candidate(model: str, data: FitInput, robust: bool) -> Calibration:
    """``model`` fitted to the samples, robustly or not; ``data`` carries their statistics and clipped rows
    (one pass over the samples saved for each).

    Through :func:`~magfit.methods.core.estimate`, like every method (:func:`~magfit.methods.robust.fit_model`
    runs ``resolve_model``'s method the same way): a candidate refuses what the method refuses for any caller."""
    if robust:
        return estimate(data, "robust", {"model": model})
    return estimate(data, resolve_model(model)[0])


def _support(report: Diagnostics) -> Support:
    """The verdict of a candidate's diagnosis (always reached by :func:`magfit.diagnostics.diagnose`)."""
    assert report.support is not None
    return report.support


def _offset_effect(chosen: Calibration, witness: Calibration, report: Diagnostics | None) -> list[float]:
    """The offset error (input units, per axis) a distortion the chosen model leaves out can cause.

    ``|V_witness − V_chosen|`` plus the witness's own offset one-sigma (its offset is known no better), as the
    heading error is the level-heading difference plus the witness's heading one-sigma.
    """
    sigma = report.uncertainty.offset_sigma if report is not None and report.uncertainty is not None else None
    effect = np.abs(np.asarray(witness.offset) - np.asarray(chosen.offset))
    if sigma is not None:
        effect = effect + np.asarray(sigma)
    return [float(value) for value in effect]


def _heading_sigma(report: Diagnostics | None) -> float | None:
    """The heading one-sigma of a candidate's diagnosis (degrees), when there is one."""
    return None if report is None or report.uncertainty is None else report.uncertainty.heading_sigma_deg


def _undetermined(report: Diagnostics) -> bool:
    """Whether a combination of the model's parameters is not determined (the verdict may still return it)."""
    return report.observability is not None and any(not w.determined for w in report.observability.weak)


def _candidate_report(optimum: Calibration, kept: NDArray[np.float64]) -> Diagnostics:
    """The diagnosis of one candidate, as :func:`magfit.fit` reaches it for any calibration (cheap checks only).

    Judged at the model's maximum-likelihood optimum: an algebraic fit that drifted along a weak direction
    (e.g. stretched along z to hug a cap of samples) makes the samples look better spread than they are;
    the distances to the ellipsoid cannot shrink by such a stretch, so the optimum does not drift that way.
    """
    rows = _stride(kept, CHOICE_ROWS)  # in recording order, each row standing for the same share of them
    return diagnose(optimum, rows, thorough=False, compare_ml=False, max_samples=CHOICE_ROWS, represents=kept.shape[0])


def _inadequate(rss: dict[str, float], n: int) -> dict[str, str]:
    """Why each simpler model that leaves far larger residuals than a richer one cannot be chosen.

    A richer model that the samples do not determine cannot be returned, but its fit still shows what the
    simpler ones miss: a sphere whose RMS distance is :data:`INADEQUATE_RATIO` times the full ellipsoid's
    (and above :data:`INADEQUATE_RMS` of the field) leaves the soft iron in the heading, by tens of
    degrees on the paper's steel case. Falling back to it would be a confident wrong calibration.
    """
    reasons: dict[str, str] = {}
    for simple in CANDIDATES:
        if simple not in rss:
            continue
        for richer in CANDIDATES[CANDIDATES.index(simple) + 1 :]:
            if richer not in rss:
                continue
            ratio = math.sqrt(rss[simple] / max(rss[richer], 1e-300))
            rms = math.sqrt(rss[simple] / n)  # the data's RMS radius is 1 in the frame of the sums: ≈ the field
            if ratio > INADEQUATE_RATIO and rms > INADEQUATE_RMS:
                reasons[simple] = (
                    f"it leaves residuals {ratio:.1f} times those of the {richer} model: the soft iron it cannot "
                    "describe would stay in the heading"
                )
                break
    return reasons


def _blocked_scores(
    kept: NDArray[np.float64], optima: dict[str, Calibration], models: list[str]
) -> dict[str, NDArray[np.float64]]:
    """Each model's mean squared distance on each of :data:`BLOCKS` contiguous blocks, fitted without it.

    Held-out blocks that respect time: a real recording carries effects no calibration model holds (a
    field that varies along the way, a vehicle's slowly changing fields), in long runs. A richer model
    can bend its weakly determined parameters to follow them within the samples it sees (the BIC, which
    counts every sample as independent evidence, then always prefers it on long logs); on a stretch of
    the recording it did not see, that bending does not help, or hurts. Each block is predicted by the
    model's first-order maximum-likelihood fit to the other blocks (Levenberg-Marquardt from the model's
    optimum on all of them), on a regular stride of at most :data:`BLOCK_ROWS` samples.
    """
    from ..geometry.frame import Frame, distances, maximum_likelihood, parameters

    rows = _stride(kept, BLOCK_ROWS)
    frame = Frame.of(rows)
    z = frame.normalise(rows)
    edges = np.linspace(0, z.shape[0], BLOCKS + 1).astype(np.int64)
    scores: dict[str, NDArray[np.float64]] = {}
    for model in models:
        start = parameters(optima[model], model, frame)
        values = np.empty(BLOCKS)
        for block in range(BLOCKS):
            held = slice(edges[block], edges[block + 1])
            train = np.concatenate([z[: edges[block]], z[edges[block + 1] :]])
            _, p = maximum_likelihood(
                train, model, [start], cost_tolerance=SCORE_TOLERANCE, max_iterations=SCORE_ITERATIONS
            )
            with np.errstate(all="ignore"):
                values[block] = float(np.mean(distances(p, z[held], model) ** 2))
        scores[model] = np.where(np.isfinite(values), values, np.inf)
    return scores


def _missed(
    chosen: str, witnesses: list[str], held_out: dict[str, NDArray[np.float64]]
) -> tuple[str, str, bool] | None:
    """The richer model that shows ``chosen`` may leave a distortion out, how, and whether clearly; or None.

    A richer model whose parameters the samples do not all determine cannot be returned, nor one that
    :func:`_choose` did not find clearly better; but unless it predicts held-out stretches of the recording
    clearly worse (by one standard error of the block differences), the samples do not rule out the
    distortion it holds and the chosen model leaves out (an aircraft's induced field on level flight). It
    clearly does when better by more than :data:`WITNESS_GAIN` and twice the standard error (the
    benchmark's generic sensor tilted ±20°: the sphere 10° of heading off, the undetermined full ellipsoid
    1°). The richest such model is named.
    """
    for witness in reversed(witnesses):
        if chosen not in held_out or witness not in held_out:
            continue
        difference = held_out[chosen] - held_out[witness]
        if not np.all(np.isfinite(difference)):
            continue
        gain = float(difference.mean())
        error = float(difference.std(ddof=1) / math.sqrt(difference.size))
        base = float(held_out[chosen].mean())
        if gain > -error:  # not clearly worse: the samples do not rule the richer model's distortion out
            clear = gain > 2.0 * error and gain > WITNESS_GAIN * base
            return (
                witness,
                f"{'leaves' if clear else 'may leave'} a distortion out: the {witness} model predicts held-out "
                f"stretches of the recording {100 * gain / base:+.1f} % better (block-to-block error "
                f"{100 * error / base:.1f} %)",
                clear,
            )
    return None


def _planar_witness(chosen: Calibration, kept: NDArray[np.float64]) -> tuple[Calibration, str] | None:
    """``chosen`` with the ellipse the samples trace in their plane in place of its section; None if none.

    Samples that lie in a plane (a sensor turned about one axis only) determine the conic they trace there
    (5 numbers) though no ellipsoid through them is determined. With ``u`` the samples' two widest principal
    directions (``P``, 3×2) and ``n`` the third, the centred in-plane coordinates ``y = Pᵀ(x − x̄)`` are fitted
    algebraically, ``yᵀ Q y + gᵀ y = 1``; the ellipse's centre is ``c = −½ Q⁻¹ g`` and its unit map
    ``M = (Q / k)^½`` with ``k = 1 + cᵀ Q c``. The witness keeps the chosen model's offset and scale along
    ``n`` (the samples say nothing there) and takes ``x̄ + P c`` in the plane with ``M`` scaled to the chosen
    model's mean in-plane scale: its headings differ from the chosen model's by the soft iron in the plane.
    """
    from ..geometry.frame import symmetric_unit_map

    rows = _stride(kept, CHOICE_ROWS)
    mean = rows.mean(axis=0)
    _, directions = np.linalg.eigh(np.cov(rows.T))
    plane, normal = directions[:, 1:], directions[:, 0]
    y = (rows - mean) @ plane
    design = np.column_stack([y[:, 0] ** 2, y[:, 0] * y[:, 1], y[:, 1] ** 2, y[:, 0], y[:, 1]])
    coefficients, *_ = np.linalg.lstsq(design, np.ones(y.shape[0]), rcond=None)
    a, b, c, d, e = coefficients
    quadratic = np.array([[a, b / 2.0], [b / 2.0, c]])
    if not np.all(np.isfinite(quadratic)) or np.linalg.eigvalsh(quadratic)[0] <= 0.0:
        return None
    centre = -0.5 * np.linalg.solve(quadratic, np.array([d, e]))
    level = 1.0 + float(centre @ quadratic @ centre)
    if level <= 0.0:
        return None
    values, vectors = np.linalg.eigh(quadratic / level)
    in_plane = (vectors * np.sqrt(values)) @ vectors.T
    unit = symmetric_unit_map(chosen)
    scale_normal = float(normal @ unit @ normal)
    scale_plane = math.sqrt(max(float(np.linalg.det(plane.T @ unit @ plane)), 1e-300))
    in_plane *= scale_plane / math.sqrt(float(np.linalg.det(in_plane)))
    witness_map = plane @ in_plane @ plane.T + scale_normal * np.outer(normal, normal)
    offset = mean + plane @ centre + normal * float(normal @ (chosen.offset - mean))
    strength = chosen.field_strength
    witness = Calibration("auto", offset, witness_map * strength, strength, n_samples=kept.shape[0])
    ratio = math.sqrt(values[1] / values[0])
    words = (
        f"leaves out the soft iron the samples show in their plane: they trace an ellipse there whose axes differ "
        f"by {100 * (ratio - 1.0):.1f} % (no ellipsoid through samples in a plane is determined)"
    )
    return witness, words


def _holds(optimum: Calibration, kept: NDArray[np.float64], model: str) -> bool:
    """Whether the verdict :func:`magfit.fit` reaches on ``model``'s fit (every check) returns it.

    The candidates are judged on the cheap checks; a model taken only because it is returned weak is judged
    as the fit returned will be (the halves, the block jackknife), so that ``auto`` never hands over a model
    its own verdict then refuses (a forced fit would return it, worse than the model passed over).
    """
    calibration = refine_chosen(model, optimum, kept) if model == "full" else optimum
    calibration = replace(calibration, method="auto", details={}, auto=AutoChoice(model=model))
    report = diagnose(
        calibration,
        kept,
        refit=lambda rows: refit_first_order(model, calibration, rows),
        compare_ml=False,
    )
    return report.support is not None and report.support.verdict != "refused"


def _choose(determined: list[str], held_out: dict[str, NDArray[np.float64]]) -> tuple[str, list[str]]:
    """The simplest determined model, replaced by a richer one only where it predicts held-out blocks better.

    A richer model wins when its mean held-out distance is lower by more than the standard error of the
    block-by-block differences (the one-standard-error rule of cross-validation, Hastie, Tibshirani &
    Friedman, *The Elements of Statistical Learning*, 2nd ed., 2009, section 7.10, on paired blocks) and
    by more than :data:`MIN_GAIN` of the simpler one's.
    Returns the model and the comparisons made, in words.
    """
    chosen = determined[0]
    steps = []
    for richer in determined[1:]:
        difference = held_out[chosen] - held_out[richer]
        if not np.all(np.isfinite(difference)):
            steps.append(f"{richer} did not predict every held-out block")
            continue
        gain = float(difference.mean())
        error = float(difference.std(ddof=1) / math.sqrt(difference.size))
        base = float(held_out[chosen].mean())
        if gain > error and gain > MIN_GAIN * base:
            steps.append(f"{richer} predicts held-out blocks {100 * gain / base:.0f} % better than {chosen}")
            chosen = richer
        else:
            share, spread = 100 * gain / max(base, 1e-300), 100 * error / max(base, 1e-300)
            steps.append(
                f"{richer} does not predict held-out blocks clearly better than {chosen} "
                f"({share:+.1f} %, block-to-block error {spread:.1f} %)"
            )
    return chosen, steps


def _flatness(samples: NDArray[np.float64]) -> str:
    """Words for the direction the samples hardly extend along, when they lie near a plane."""
    from ..geometry.frame import axis_words

    spreads, directions = np.linalg.eigh(np.cov(samples.T))
    ratio = math.sqrt(max(spreads[0], 0.0) / spreads[2])
    if ratio > 0.25:
        return ""
    axis = axis_words(directions[:, 0] * np.sign(directions[np.argmax(np.abs(directions[:, 0])), 0])).lstrip("+")
    return (
        f" (they lie close to a plane: their spread along {axis} is {100 * ratio:.0f} % of the largest, so the "
        f"sensor turned mostly about {axis} and the offset and scale along {axis} are not determined)"
    )


def _reason(
    best: str,
    chosen: str,
    opening: str,
    bic: dict[str, float],
    steps: list[str],
    passed_over: list[str],
    failed: dict[str, str],
    screen_note: str,
) -> str:
    scores = ", ".join(f"{model} {value:.1f}" for model, value in sorted(bic.items(), key=lambda item: item[1]))
    parts = [f"{chosen} model: {opening}"]
    parts.extend(passed_over)
    parts.extend(steps)
    parts.append(f"lowest BIC: {best} (BIC {scores})")
    # The chosen model's weaknesses, with the heading uncertainty they leave, are its verdict's (the warnings):
    # one uncertainty, computed once, on the calibration returned.
    if failed:
        parts.append("could not fit: " + ", ".join(sorted(failed)))
    if screen_note:
        parts.append(screen_note)
    return "; ".join(parts)
