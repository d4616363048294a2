"""The verdict of a vector fit: :func:`magfit.diagnostics.reference.judge_reference_fit` on the samples the fit
read, at the joint fit with its covariance when the accelerometer's gravity equations joined it (its notes
and cautions with it), and the calibration with its facts."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from ...calibration import Calibration
from ...diagnostics.reference import judge_reference_fit
from ...facts import VectorFacts
from .gravity import GravityFit
from .lag import _Lagged


def _judged(lag: _Lagged, g: NDArray[Any], offset: NDArray[Any], field: float,
            joint: GravityFit | None, details: dict[str, Any]) -> Calibration:  # fmt: skip
    """The calibration ``matrix = G⁻¹``, ``offset = V`` with the verdict (module docstring of
    :mod:`magfit.methods.vector.method`); ``joint`` is the gravity equations' outcome (None without accel)."""
    used_raw, used_ref, rate, lag_limit, jackknife = lag.raw, lag.reference, lag.rate, lag.lag_limit, lag.jackknife
    covariance = prior = None
    notes: tuple[str, ...] = ()
    cautions: tuple[str, ...] = ()
    gravity = None
    if joint is not None:
        gravity = joint.facts
        notes = (joint.note,)
        cautions = () if joint.caution is None else (joint.caution,)
        if joint.g is not None and joint.offset is not None:
            g, offset, covariance, prior = joint.g, joint.offset, joint.covariance, joint.prior
    report = judge_reference_fit(
        used_raw, used_ref, g, offset, rate=rate, lag_at_limit=lag_limit, covariance=covariance, prior=prior,
        notes=notes, cautions=cautions,
    )  # fmt: skip
    lag_sigma = None
    if rate is not None:  # the larger of the lag search's jackknife and the fit's covariance (when it has the lag)
        lag_variance = report.covariance[12, 12] if report.covariance.shape[0] > 12 else 0.0
        lag_sigma = max(jackknife, float(np.sqrt(max(lag_variance, 0.0))))
    facts = VectorFacts(lag.lag_s, lag_sigma, report.rotation_sigma_deg, gravity)
    details["residual_rms"] = report.residual_rms
    details["scale"] = report.scale
    details["diagnostics"] = report.diagnostics(int(used_raw.shape[0])).to_dict()
    return Calibration(
        "vector", offset, np.linalg.inv(g), field, n_samples=int(used_raw.shape[0]), details=details, frame="vehicle",
        support=report.support, vector=facts,
    )  # fmt: skip
