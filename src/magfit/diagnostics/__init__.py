"""Honest diagnostics for every calibration: the support verdict, coverage, observability, uncertainty, fit.

``magfit.fit`` judges every calibration with them before returning it (the verdict:
:mod:`magfit.diagnostics.verdict`) and attaches them (``calibration.details["diagnostics"]``, read back
typed with ``calibration.diagnostics``); ``magfit.diagnose`` computes them for any calibration and samples.

This package never imports :mod:`magfit.methods`: the checks that refit the method (held-out samples, the
two halves of the recording) receive the refit as a function.

To keep ``fit`` fast on long logs, the diagnostics run on a capped, spatially even subsample (at most
:data:`MAX_SAMPLES` samples, the same number from every direction cell where possible, each row
weighted by how many samples it stands for so that the uncertainty still reflects all of them); the
correlation of samples in time is measured on a regular stride of the recording. See
``docs/diagnostics.md`` for what each figure means and what to do about it.
"""

from ..findings import Diagnostics, Goodness, Support
from ..sampling import thin, weighted_even_subsample
from .coverage import Coverage
from .diagnose import MAX_SAMPLES, Refit, diagnose, diagnose_statistics, flat_axis, model_kind
from .uncertainty import DEFAULT_INCLINATION_DEG, Consistency, Observability, Uncertainty, WeakDirection

__all__ = [
    "DEFAULT_INCLINATION_DEG",
    "MAX_SAMPLES",
    "Consistency",
    "Coverage",
    "Diagnostics",
    "Goodness",
    "Observability",
    "Refit",
    "Support",
    "Uncertainty",
    "WeakDirection",
    "diagnose",
    "diagnose_statistics",
    "flat_axis",
    "model_kind",
    "thin",
    "weighted_even_subsample",
]
