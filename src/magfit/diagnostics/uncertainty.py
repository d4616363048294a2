"""How well the samples determine a calibration: observability and parameter uncertainty.

Both come from the Jacobian J of the geometric residual ``r = |L (x − V)| − 1`` (see
:mod:`magfit.diagnostics._geometry`) at the fitted calibration, in the calibration's corrected frame,
where its parameters are ``v = 0, L = I``: an offset there is a fraction of the field strength along
the corrected axes, a change of L a relative change of scale.

- Gauss-Newton covariance (e.g. Seber & Wild, *Nonlinear Regression*, 1989, eq. 2.8):
  ``Cov(p) = σ² (Jᵀ W J)⁻¹`` with ``σ² = Σ wᵢ dᵢ² / (Σ wᵢ − k)``, dᵢ the distance of sample i to the
  ellipsoid in the isotropic frame ``(x − V) / B`` (where the sensor noise is isotropic) and wᵢ its
  weight (how many samples it stands for when the analysis runs on a subsample). It assumes
  independent samples: with time-correlated noise (sample-and-hold, slow drifts) the true spread is
  larger.
- Observability: the eigenvectors of the per-sample information ``F = Jᵀ W J / Σ wᵢ``. A direction u
  is weakly determined when ``uᵀ F u`` is small compared with what a full, uniform tumble gives
  (``uᵀ F_tumble u``); it is not determined when its one-sigma ``σ / √(Σwᵢ uᵀ F u)`` exceeds 5 % of the
  field.
- Heading: at level attitude the corrected field is ``f(ψ) = (cos δ cos ψ, cos δ sin ψ, sin δ)``, seen
  at ``y = L⁻¹ f``; a parameter error dp moves it by ``dw = dL y − L dv``; the heading moves by
  ``dψ = h⊥ · dw / cos δ`` (h⊥ the horizontal unit vector at right angles to the field), so
  ``σ_ψ² = gᵀ Cov g`` with ``g = h⊥ᵀ ∂w/∂p / cos δ``, averaged over ψ. The inclination δ is an
  assumption (default 60°): the error grows as ``1 / cos δ`` towards the magnetic poles.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..calibration import Calibration
from ._geometry import (
    N_PARAMETERS,
    Frame,
    describe_parameter_direction,
    distance_jacobian,
    distances,
    parameters,
    symmetric_unit_map,
    unit_map,
)

__all__ = ["Consistency", "Observability", "Uncertainty", "WeakDirection", "analyse", "consistency"]

#: A direction carrying less than this share of a full tumble's information is weakly determined.
WEAK_INFORMATION = 0.05
#: A direction whose one-sigma exceeds this fraction of the field strength is not determined.
UNDETERMINED_SIGMA = 0.05
#: Default magnetic inclination assumed for the heading uncertainty, degrees.
DEFAULT_INCLINATION_DEG = 60.0


@dataclass(frozen=True)
class WeakDirection:
    """A combination of parameters the samples pin down poorly.

    Attributes
    ----------
    description : str
        The parameters it moves, in words ("the offset along z together with the scale along z").
    relative_information : float
        Its information per sample divided by what a full uniform tumble gives (1 = as good).
    sigma : float or None
        Its one-sigma, as a fraction of the field strength (None: not determined at all, or not computed:
        a diagnosis from ``Statistics`` gives none).
    determined : bool
        False when ``sigma`` exceeds 5 % of the field (without a sigma: when the information is below
        1/1000 of a tumble's, or zero).
    vector : tuple of float
        The unit direction in parameter space (corrected frame; layout of ``parameter_names``).
    """

    description: str
    relative_information: float
    sigma: float | None
    determined: bool
    vector: tuple[float, ...]

    def to_dict(self) -> dict[str, Any]:
        return {
            "description": self.description,
            "relative_information": self.relative_information,
            "sigma": self.sigma,
            "determined": self.determined,
            "vector": list(self.vector),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> WeakDirection:
        return cls(
            description=str(data["description"]),
            relative_information=float(data["relative_information"]),
            sigma=None if data["sigma"] is None else float(data["sigma"]),
            determined=bool(data["determined"]),
            vector=tuple(float(v) for v in data["vector"]),
        )

    def sentence(self) -> str:
        share = self.relative_information
        amount = (
            f"{share:.2g} of the information a full tumble gives"
            if share >= 0.01
            else f"1/{1 / max(share, 1e-12):.0f} of the information a full tumble gives"
        )
        if self.sigma is None:
            state = "is weakly determined" if self.determined else "is not determined"
            return f"{_capital(self.description)} {state} (the samples carry {amount})."
        if not self.determined:
            return (
                f"{_capital(self.description)} is not determined (one-sigma {100 * self.sigma:.1f} % of the field; "
                f"the samples carry {amount})."
            )
        return (
            f"{_capital(self.description)} is weakly determined (one-sigma {100 * self.sigma:.2f} % of the "
            f"field; the samples carry {amount})."
        )


def _capital(text: str) -> str:
    return text[:1].upper() + text[1:]


@dataclass(frozen=True)
class Observability:
    """How well the samples determine each part of the model.

    Attributes
    ----------
    model : {"sphere", "diag", "full"}
        The parameterisation analysed (from the calibration's structure).
    condition : float
        Largest over smallest eigenvalue of the per-sample information (corrected frame); a full tumble
        gives about 3, larger is worse, inf when a direction is not determined at all.
    weak : tuple of WeakDirection
        The weakly or not determined directions, weakest first.
    turn_axis : str or None
        When the field direction in the sensor frame moved only on a cone (the sensor turned about one
        axis), that axis ("+z", "+x−y" ...); else None.
    """

    model: str
    condition: float | None
    weak: tuple[WeakDirection, ...]
    turn_axis: str | None

    @property
    def determined(self) -> bool:
        """True when every direction is determined (weak ones included)."""
        return all(w.determined for w in self.weak)

    def to_dict(self) -> dict[str, Any]:
        return {
            "model": self.model,
            "condition": self.condition,
            "weak": [w.to_dict() for w in self.weak],
            "turn_axis": self.turn_axis,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Observability:
        return cls(
            model=str(data["model"]),
            condition=None if data["condition"] is None else float(data["condition"]),
            weak=tuple(WeakDirection.from_dict(w) for w in data["weak"]),
            turn_axis=data.get("turn_axis"),
        )

    def summary(self) -> list[str]:
        condition = "unbounded" if self.condition is None else f"{self.condition:.3g}"
        if not self.weak:
            return [
                f"Observability: every parameter of the {self.model} model is well determined (condition {condition})."
            ]
        lines = [f"Observability: condition {condition} for the {self.model} model (a full tumble gives about 3)."]
        if self.turn_axis is not None:
            lines.append(
                f"The sensor only turned about its {self.turn_axis} axis: directions off that cone were never seen."
            )
        lines.extend(w.sentence() for w in self.weak)
        return lines


@dataclass(frozen=True)
class Uncertainty:
    """One-sigma uncertainty of the calibration implied by the residuals and the sample geometry.

    Attributes
    ----------
    offset_sigma : tuple of 3 float or None
        One-sigma of the hard-iron offset along x, y, z, input units (None: not determined).
    scale_sigma : tuple of 3 float or None
        Relative one-sigma of the correction's scale along x, y, z (0.01 = 1 %).
    field_strength_sigma : float or None
        Relative one-sigma of the field strength.
    heading_sigma_deg : float or None
        RMS over all headings of the heading one-sigma at level attitude, degrees.
    heading_sigma_max_deg : float or None
        The worst heading's one-sigma, degrees.
    inclination_deg : float
        The inclination assumed for the heading figures.
    residual_sigma : float
        Standard deviation of the geometric residual, fraction of the field strength.
    n_samples : int
        Samples the information was scaled to (all samples the fit used, assumed independent).
    """

    offset_sigma: tuple[float, float, float] | None
    scale_sigma: tuple[float, float, float] | None
    field_strength_sigma: float | None
    heading_sigma_deg: float | None
    heading_sigma_max_deg: float | None
    inclination_deg: float
    residual_sigma: float
    n_samples: int

    def to_dict(self) -> dict[str, Any]:
        return {
            "offset_sigma": None if self.offset_sigma is None else list(self.offset_sigma),
            "scale_sigma": None if self.scale_sigma is None else list(self.scale_sigma),
            "field_strength_sigma": self.field_strength_sigma,
            "heading_sigma_deg": self.heading_sigma_deg,
            "heading_sigma_max_deg": self.heading_sigma_max_deg,
            "inclination_deg": self.inclination_deg,
            "residual_sigma": self.residual_sigma,
            "n_samples": self.n_samples,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Uncertainty:
        def triple(value: Any) -> tuple[float, float, float] | None:
            return None if value is None else (float(value[0]), float(value[1]), float(value[2]))

        def number(value: Any) -> float | None:
            return None if value is None else float(value)

        return cls(
            offset_sigma=triple(data["offset_sigma"]),
            scale_sigma=triple(data["scale_sigma"]),
            field_strength_sigma=number(data["field_strength_sigma"]),
            heading_sigma_deg=number(data["heading_sigma_deg"]),
            heading_sigma_max_deg=number(data["heading_sigma_max_deg"]),
            inclination_deg=float(data["inclination_deg"]),
            residual_sigma=float(data["residual_sigma"]),
            n_samples=int(data["n_samples"]),
        )

    def summary(self, unit: str | None = None) -> list[str]:
        label = f" {unit}" if unit else ""
        if self.offset_sigma is None or self.heading_sigma_deg is None:
            return [
                "Uncertainty: not available: part of the model is not determined by the samples "
                "(see observability), so any number would be noise."
            ]
        offset = ", ".join(f"{value:.3g}" for value in self.offset_sigma)
        lines = [f"Uncertainty (one-sigma): offset ± ({offset}){label} along x, y, z."]
        if self.scale_sigma is not None:
            scales = ", ".join(f"{100 * value:.2g}" for value in self.scale_sigma)
            lines.append(f"Scale ± ({scales}) % along x, y, z.")
        lines.append(
            f"Heading at level attitude: ± {self.heading_sigma_deg:.2g}° (RMS over headings; worst "
            f"± {self.heading_sigma_max_deg:.2g}°), for an inclination of {self.inclination_deg:.0f}°."
        )
        return lines


def _parameter_field_map(kind: str, y: NDArray[np.float64], lmat: NDArray[np.float64]) -> NDArray[np.float64]:
    """∂w/∂p of ``w = L (z − v)`` at the point ``y = z − v``: −L along v, ``E y`` along an entry of L; (3, k)."""
    columns = [-lmat]
    if kind == "sphere":
        columns.append(y[:, None])
    else:
        columns.append(np.diag(y))
        if kind == "full":
            cross = np.zeros((3, 3))
            for column, (j, k) in enumerate(((0, 1), (0, 2), (1, 2))):
                cross[j, column] += y[k]
                cross[k, column] += y[j]
            columns.append(cross)
    return np.hstack(columns)


@functools.lru_cache(maxsize=4)
def _tumble_information(kind: str) -> NDArray[np.float64]:
    """Per-sample information of a full uniform tumble on the unit sphere (Fibonacci lattice, 4000 points)."""
    n = 4000
    index = np.arange(n) + 0.5
    z = 1.0 - 2.0 * index / n
    longitude = math.pi * (1.0 + math.sqrt(5.0)) * index
    radius = np.sqrt(1.0 - z**2)
    points = np.column_stack([radius * np.cos(longitude), radius * np.sin(longitude), z])
    jac = distance_jacobian(_identity_parameters(kind), points, kind)
    return np.asarray(jac.T @ jac / n)


def _identity_parameters(kind: str) -> NDArray[np.float64]:
    p = np.zeros(N_PARAMETERS[kind])
    p[3 : 4 if kind == "sphere" else 6] = 1.0
    return p


def _turn_axis(z: NDArray[np.float64], weights: NDArray[np.float64]) -> str | None:
    """The axis the field direction turned about, when it stayed on a cone (spread < 0.05 along it)."""
    from ._geometry import axis_words

    directions = z / np.linalg.norm(z, axis=1)[:, None]
    mean = np.average(directions, axis=0, weights=weights)
    centred = directions - mean
    covariance = (centred * weights[:, None]).T @ centred / weights.sum()
    spreads, axes = np.linalg.eigh(covariance)
    if spreads[0] < 0.05**2 and spreads[0] < 0.01 * spreads[1]:
        return axis_words(axes[:, 0] * (1.0 if axes[np.argmax(np.abs(axes[:, 0])), 0] > 0 else -1.0))
    return None


def analyse(
    raw: NDArray[np.float64],
    weights: NDArray[np.float64],
    kind: str,
    calibration: Calibration,
    inclination_deg: float,
) -> tuple[Observability, Uncertainty]:
    """Observability and uncertainty of ``calibration`` (a model of ``kind``) on raw samples.

    Parameters
    ----------
    raw : ndarray, shape (n, 3)
        The samples (or a subsample), input units.
    weights : ndarray, shape (n,)
        How many of the fitted samples each row stands for (sum = samples the fit used).
    kind : {"sphere", "diag", "full"}
    calibration : Calibration
    inclination_deg : float
        Inclination assumed for the heading uncertainty, degrees.
    """
    z = Frame.corrected(calibration).normalise(raw)
    p = _identity_parameters(kind)
    k = p.size
    # The distance's Jacobian, not r's: r can also shrink by stretching the ellipsoid along a direction the
    # samples do not cover, which would count as information the samples do not hold.
    jac = distance_jacobian(p, z, kind)
    residual = np.linalg.norm(z, axis=1) - 1.0
    total = float(weights.sum())
    information = (jac * weights[:, None]).T @ jac  # Jᵀ W J
    dof = max(total - k, 1.0)
    residual_variance = float(np.sum(weights * residual**2) / dof)
    condition, weak, null = _weak_directions(information, residual_variance, total, kind)
    observability = Observability(kind, condition, weak, _turn_axis(z, weights))
    n_samples = round(total)
    if null:
        return observability, Uncertainty(
            None, None, None, None, None, float(inclination_deg), math.sqrt(residual_variance), n_samples
        )
    return observability, _uncertainty(raw, weights, kind, calibration, inclination_deg, n_samples)


def _weak_directions(
    information: NDArray[np.float64], residual_variance: float, total: float, kind: str
) -> tuple[float | None, tuple[WeakDirection, ...], bool]:
    """Condition, weak directions (weakest first) and whether one is not determined at all, from JᵀWJ."""
    k = information.shape[0]
    eigenvalues, eigenvectors = np.linalg.eigh(information / total)
    tumble = _tumble_information(kind)
    largest = float(eigenvalues[-1])
    null = eigenvalues <= 1e-10 * largest
    condition = None if null.any() else float(largest / eigenvalues[0])
    weak: list[WeakDirection] = []
    for i in range(k):
        vector = eigenvectors[:, i]
        relative = float(eigenvalues[i] / (vector @ tumble @ vector))
        if relative >= WEAK_INFORMATION:
            continue
        sigma = None if null[i] else math.sqrt(residual_variance / (total * float(eigenvalues[i])))
        weak.append(
            WeakDirection(
                description=describe_parameter_direction(vector, kind),
                relative_information=max(relative, 0.0),
                sigma=sigma,
                determined=sigma is not None and sigma <= UNDETERMINED_SIGMA,
                vector=tuple(float(v) for v in vector),
            )
        )
    return condition, tuple(weak), bool(null.any())


def _uncertainty(
    raw: NDArray[np.float64],
    weights: NDArray[np.float64],
    kind: str,
    calibration: Calibration,
    inclination_deg: float,
    n_samples: int,
) -> Uncertainty:
    """The Gauss-Newton covariance of the distances to the ellipsoid, in the isotropic frame (x − V) / B.

    The noise is isotropic on the raw samples, so the residual whose covariance formula holds is the
    distance to the ellipsoid measured there (``_geometry.distances``), not the residual in the corrected
    space, whose noise is stretched by the soft-iron correction.
    """
    strength = calibration.field_strength
    frame = Frame(np.array(calibration.offset), np.eye(3) / strength)
    z = frame.normalise(raw)
    p = parameters(calibration, kind, frame)
    k = p.size
    lmat = unit_map(p, kind)
    distance = distances(p, z, kind)
    jac = distance_jacobian(p, z, kind)
    total = float(weights.sum())
    residual_variance = float(np.sum(weights * distance**2) / max(total - k, 1.0))
    information = (jac * weights[:, None]).T @ jac  # Jᵀ W J
    covariance = residual_variance * np.linalg.inv(information)  # Cov(p) = σ² (Jᵀ W J)⁻¹
    return _report(covariance, kind, lmat, strength * np.eye(3), inclination_deg, residual_variance, n_samples)


def _report(
    covariance: NDArray[np.float64],
    kind: str,
    lmat: NDArray[np.float64],
    offset_map: NDArray[np.float64],
    inclination_deg: float,
    residual_variance: float,
    n_samples: int,
) -> Uncertainty:
    """One-sigma figures from Cov(p) of parameters (v, L) whose offset moves V by ``offset_map @ v``."""
    k = covariance.shape[0]
    offset_sigma = np.sqrt(np.diag(offset_map @ covariance[:3, :3] @ offset_map.T))
    inverse = np.linalg.inv(lmat)
    if kind == "sphere":
        scale_sigma: tuple[float, ...] = (math.sqrt(covariance[3, 3]) / lmat[0, 0],) * 3
        strength_gradient = np.zeros(k)
        strength_gradient[3] = -1.0 / lmat[0, 0]  # B ∝ 1 / l
    else:
        scale_sigma = tuple(math.sqrt(covariance[i, i]) / lmat[i - 3, i - 3] for i in range(3, 6))
        # B ∝ det(L)^(−1/3): d ln B = −⅓ tr(L⁻¹ dL)
        strength_gradient = np.zeros(k)
        strength_gradient[3:6] = -np.diag(inverse) / 3.0
        if kind == "full":
            strength_gradient[6:9] = [-2.0 * inverse[j, m] / 3.0 for j, m in ((0, 1), (0, 2), (1, 2))]
    strength_sigma = math.sqrt(float(strength_gradient @ covariance @ strength_gradient))
    delta = math.radians(inclination_deg)
    heading_variances = []
    for psi in np.radians(np.arange(0.0, 360.0, 5.0)):
        field = np.array([math.cos(delta) * math.cos(psi), math.cos(delta) * math.sin(psi), math.sin(delta)])
        across = np.array([-math.sin(psi), math.cos(psi), 0.0])  # h⊥
        field_map = _parameter_field_map(kind, inverse @ field, lmat)
        gradient = across @ field_map / math.cos(delta)  # dψ = h⊥·dw / cos δ
        heading_variances.append(float(gradient @ covariance @ gradient))
    heading = np.degrees(np.sqrt(np.array(heading_variances)))
    return Uncertainty(
        offset_sigma=(float(offset_sigma[0]), float(offset_sigma[1]), float(offset_sigma[2])),
        scale_sigma=(float(scale_sigma[0]), float(scale_sigma[1]), float(scale_sigma[2])),
        field_strength_sigma=strength_sigma,
        heading_sigma_deg=float(np.sqrt(np.mean(heading**2))),
        heading_sigma_max_deg=float(heading.max()),
        inclination_deg=float(inclination_deg),
        residual_sigma=math.sqrt(residual_variance),
        n_samples=n_samples,
    )


@dataclass(frozen=True)
class Consistency:
    """How far the calibration is from the maximum-likelihood fit of the same model on the same samples.

    The uncertainty describes the noise of the maximum-likelihood estimate, linearised at the calibration.
    A biased estimator (the algebraic fits under strong noise or poor coverage, min/max) can sit far from
    it, where the linearisation looks reassuring; this comparison shows that bias.

    Attributes
    ----------
    offset_difference : tuple of 3 float
        Calibration offset minus the maximum-likelihood offset, input units.
    sigmas : float
        That difference in units of the offset's one-sigma (Mahalanobis distance with the diagonal
        one-sigmas; None when the uncertainty is not available).
    heading_difference_deg : float
        RMS over level headings of the heading difference between the two, degrees (same inclination as
        the uncertainty).
    consistent : bool
        False when the difference exceeds 3 one-sigmas and 0.1° of heading.
    """

    offset_difference: tuple[float, float, float]
    sigmas: float | None
    heading_difference_deg: float
    consistent: bool

    def to_dict(self) -> dict[str, Any]:
        return {
            "offset_difference": list(self.offset_difference),
            "sigmas": self.sigmas,
            "heading_difference_deg": self.heading_difference_deg,
            "consistent": self.consistent,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Consistency:
        values = data["offset_difference"]
        return cls(
            offset_difference=(float(values[0]), float(values[1]), float(values[2])),
            sigmas=None if data["sigmas"] is None else float(data["sigmas"]),
            heading_difference_deg=float(data["heading_difference_deg"]),
            consistent=bool(data["consistent"]),
        )

    def summary(self, unit: str | None = None) -> list[str]:
        label = f" {unit}" if unit else ""
        offset = ", ".join(f"{value:+.3g}" for value in self.offset_difference)
        size = "" if self.sigmas is None else f" ({self.sigmas:.1f} one-sigmas)"
        if self.sigmas is None or self.sigmas <= 3.0:
            verdict = "within the uncertainty"
        elif self.consistent:
            verdict = "beyond the offset's uncertainty, but less than 0.1° of level heading"
        else:
            verdict = "beyond the uncertainty: this fit is biased, prefer method='auto' (or 'ml', 'als')"
        return [
            f"Consistency: the maximum-likelihood fit of the same model differs by ({offset}){label} in offset"
            f"{size} and by {self.heading_difference_deg:.2g}° in level heading: {verdict}."
        ]


def consistency(
    raw: NDArray[np.float64],
    kind: str,
    calibration: Calibration,
    uncertainty: Uncertainty,
    inclination_deg: float,
) -> Consistency | None:
    """Compare ``calibration`` with the maximum-likelihood fit of its model on ``raw`` (None if that fails)."""
    from ..errors import MagfitError
    from ._geometry import calibration_from_parameters, maximum_likelihood

    frame = Frame(np.array(calibration.offset), np.eye(3) / calibration.field_strength)
    z = frame.normalise(raw)
    try:
        _, optimum = maximum_likelihood(z, kind, [parameters(calibration, kind, frame)])
        reference = calibration_from_parameters(optimum, kind, frame, kind)
    except (MagfitError, np.linalg.LinAlgError):
        return None
    difference = np.asarray(calibration.offset - reference.offset, dtype=np.float64)
    sigmas = None
    if uncertainty.offset_sigma is not None:
        # The reference is fitted on a subset of the samples the uncertainty stands for: its own noise,
        # larger by sqrt(N / n), must not read as a bias of the calibration.
        subset = math.sqrt(max(float(uncertainty.n_samples) / max(raw.shape[0], 1), 1.0))
        scale = np.maximum(np.asarray(uncertainty.offset_sigma) * subset, 1e-300)
        sigmas = float(np.sqrt(np.sum((difference / scale) ** 2)))
    # Level headings seen by both: the reference's corrected field f(ψ), mapped back to raw readings.
    delta = math.radians(inclination_deg)
    psi = np.radians(np.arange(0.0, 360.0, 2.0))
    field = np.column_stack(
        [math.cos(delta) * np.cos(psi), math.cos(delta) * np.sin(psi), np.full(psi.size, math.sin(delta))]
    )
    readings = reference.offset + field @ np.linalg.inv(symmetric_unit_map(reference)).T
    seen = (readings - calibration.offset) @ symmetric_unit_map(calibration).T
    angle = np.arctan2(seen[:, 1], seen[:, 0]) - np.arctan2(field[:, 1], field[:, 0])
    angle = (angle + math.pi) % (2.0 * math.pi) - math.pi
    heading = float(np.degrees(np.sqrt(np.mean(angle**2))))
    consistent = (sigmas is None or sigmas <= 3.0) or heading <= 0.1
    return Consistency(
        offset_difference=(float(difference[0]), float(difference[1]), float(difference[2])),
        sigmas=sigmas,
        heading_difference_deg=heading,
        consistent=consistent,
    )
