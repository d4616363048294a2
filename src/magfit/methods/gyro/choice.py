"""Stage 3: the model of G the samples choose, the general one or a standard mapping's ``W Pᵀ``.

The candidates (the mapping nearest the general fit's rotation, and the two best of all 24 on the windows of
stage 1, whose noise hides the differences on a vehicle that hardly tilts) are fitted as in stage 2 on a
stride of the recording and compared with the general G by their likelihood ratio::

    Λ = (RSS_mapping − RSS_general) / σ²                                          (C1)

(σ² the general fit's residual variance per component times its correlation excess in time). With
independent residuals Λ would be χ² with 3 degrees of freedom for the right mapping. The best is kept
unless the general G beats it by more than :data:`LIKELIHOOD_RATIO` (the mounting is then turned in between:
the rotation and its angle from the nearest mapping are reported). W must be definite: an indefinite W is P
times a half turn about W's eigenvectors, another mounting than the label. Two candidates that fit alike
but turn differently (rotations about one axis cannot tell mappings that differ by a turn about it) are a
refusal: the alignment is not determined.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ...errors import CalibrationError
from ...rotations import angle_between_deg, polar_decomposition
from .gravity import _Gravity
from .inclination import _weighted
from .mapping import MAPPINGS, mapping_name
from .model import LINEAR_TURN, SCREEN_ITER, SCREEN_ROWS, _fit_model, _Model, _noise_variance, _parts
from .rates import _check_handedness
from .windows import _constrained, _design, _symmetric, _windowed_bias, _Windows

#: Likelihood ratio (residual excess in noise variances) that tells two models of G apart. With independent
#: residuals it would be χ² with 3 degrees of freedom (above 25 with probability 2e-5); the gyro's noise
#: walks, so the right mapping's ratio runs higher (docs/methods.md, "gyro").
LIKELIHOOD_RATIO = 50.0


def _definite(model: _Model) -> bool:
    """True when the symmetric W of a mapping's model ``G = W Pᵀ`` has eigenvalues of one sign."""
    w = model.traj.distortion(model.solution.params) @ MAPPINGS[model.name]
    values = np.linalg.eigvalsh(0.5 * (w + w.T))
    return bool(values.min() > 0 or values.max() < 0)


def _rotation(model: _Model) -> NDArray[np.float64]:
    """The rotation part of a fitted model's correction, taken proper (:mod:`.mapping`: the sign is free)."""
    g = model.traj.distortion(model.solution.params)
    h = np.linalg.inv(g)
    return polar_decomposition(h * np.sign(np.linalg.det(h)))[0]


def _windowed_ranking(design: NDArray[np.float64]) -> list[str]:
    """The 24 standard mappings ``H = P S`` ranked by the windowed residual (best first): cheap, and a
    shortlist only, for on a vehicle that hardly tilts the windows' noise hides the differences."""
    residual = {name: _constrained(design, _symmetric(p, np.eye(3)))[2] for name, p in MAPPINGS.items()}
    return sorted(residual, key=residual.__getitem__)


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
    general = _fit_model(y, w, t, segment_s, "general", inverse, offset, beta, SCREEN_ROWS, turn=LINEAR_TURN)
    _check_handedness(y, w, t, win, segment_s, general)
    if gravity is not None:
        # The weight from the kinematic fit's residuals, then once more from the fit with the gravity rows:
        # the first residuals carry the fit's own error in the direction the gravity rows pin.
        for _ in range(2):
            gravity = _weighted(general, gravity)
            general = _fit_model(y, w, t, segment_s, "general", *_parts(general), SCREEN_ROWS, gravity=gravity,
                                     turn=LINEAR_TURN)  # fmt: skip
    chosen, excess, ambiguous = general, {}, None
    if mapping != "general":
        if mapping in MAPPINGS:
            names = [mapping]
        else:
            g = general.traj.distortion(general.solution.params)
            rotation, _ = polar_decomposition(np.linalg.inv(g) * np.sign(np.linalg.det(g)))
            names = list(dict.fromkeys([mapping_name(rotation), *_windowed_ranking(design)[:2]]))
        start = _parts(general)
        fitted = [_fit_model(y, w, t, segment_s, name, *start, SCREEN_ROWS, SCREEN_ITER, gravity, turn=LINEAR_TURN)
                  for name in names]  # fmt: skip
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
            rivals = [m for m in screened[1:] if angle_between_deg(_rotation(m), _rotation(best)) > 10.0]
            if mapping == "search" and rivals:
                separation = excess[rivals[0].name] - excess[best.name]
                if separation < LIKELIHOOD_RATIO:
                    ambiguous = (mapping_name(_rotation(best)), mapping_name(_rotation(rivals[0])), separation)
    return _fit_model(y, w, t, segment_s, chosen.name, *_parts(chosen), gravity=gravity), excess, ambiguous
