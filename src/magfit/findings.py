"""The typed findings a calibration carries: the paper's metric, coverage, observability, uncertainty,
consistency, goodness of fit, the support verdict, and the :class:`Diagnostics` that holds them.

Plain data with ``to_dict`` / ``from_dict`` (the layout stored in ``Calibration.details``) and
``summary()`` lines in words. Nothing here computes a finding: :mod:`magfit.evaluate` and
:mod:`magfit.diagnostics` do. This module sits below :mod:`magfit.calibration` (which reads the
diagnostics back typed), so it imports nothing of magfit but the errors.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any, Literal

from .errors import MagfitError
from .remedy import option

__all__ = [
    "AXIS_DIRECTIONS",
    "REASON_CODES",
    "Consistency",
    "Coverage",
    "Diagnostics",
    "Evaluation",
    "Goodness",
    "Observability",
    "Reason",
    "ReasonList",
    "Support",
    "Uncertainty",
    "WeakDirection",
    "reasons",
    "said_once",
]

_SCHEMA = 1
_VERDICT_WORDS = {
    "supported": "supported by the samples",
    "weak": "supported, with weaknesses",
    "refused": "NOT supported",
}


@dataclass(frozen=True)
class Evaluation:
    """Summary of the sphere distances (dimensionless, fractions of the field strength).

    ``mean`` and ``std`` are the paper's two columns (``std`` is the population standard deviation).
    """

    n: int
    mean: float
    std: float
    mean_abs: float
    rms: float
    max_abs: float

    def to_dict(self) -> dict[str, float | int]:
        return {
            "n": self.n,
            "mean": self.mean,
            "std": self.std,
            "mean_abs": self.mean_abs,
            "rms": self.rms,
            "max_abs": self.max_abs,
        }


#: The six sensor half-axes coverage is described by, with their unit vectors.
AXIS_DIRECTIONS: dict[str, tuple[float, float, float]] = {
    "+x": (1.0, 0.0, 0.0),
    "−x": (-1.0, 0.0, 0.0),
    "+y": (0.0, 1.0, 0.0),
    "−y": (0.0, -1.0, 0.0),
    "+z": (0.0, 0.0, 1.0),
    "−z": (0.0, 0.0, -1.0),
}


@dataclass(frozen=True)
class Coverage:
    """How much of the sphere of field directions the calibrated samples reach.

    Attributes
    ----------
    cells : int
        Number of equal-area cells (100, as MotionCal).
    cells_reached : int
        Cells holding at least one sample.
    share : float
        ``cells_reached / cells``, 0 to 1.
    axis_shares : dict
        For each sensor half-axis ("+x", "−x", ... "−z"), the share of the cells within 45° of it that
        are reached.
    missing : tuple of str
        Half-axes with less than 25 % of their cells reached: directions the field was (almost) never
        seen along.
    sparse : tuple of str
        Half-axes with 25 % to 75 % of their cells reached.
    """

    cells: int
    cells_reached: int
    share: float
    axis_shares: dict[str, float]
    missing: tuple[str, ...]
    sparse: tuple[str, ...]

    @property
    def unseen_axes(self) -> tuple[str, ...]:
        """Sensor axes ("x", "y", "z") the samples form a band around: the field was seen at neither end of
        the axis (both half-axes missing) but along the four half-axes at right angles to it.

        Nothing in such samples fixes the offset or the scale along that axis, whatever a fit returns.
        (A cap of directions, as from a vehicle that only tilts a little, misses more than that and is
        left to the observability analysis.)
        """
        unseen = []
        for axis in "xyz":
            others = [f"{sign}{other}" for other in "xyz" if other != axis for sign in ("+", "−")]
            ends_missing = f"+{axis}" in self.missing and f"−{axis}" in self.missing
            if ends_missing and not any(half in self.missing for half in others):
                unseen.append(axis)
        return tuple(unseen)

    def to_dict(self) -> dict[str, Any]:
        return {
            "cells": self.cells,
            "cells_reached": self.cells_reached,
            "share": self.share,
            "axis_shares": dict(self.axis_shares),
            "missing": list(self.missing),
            "sparse": list(self.sparse),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Coverage:
        return cls(
            cells=int(data["cells"]),
            cells_reached=int(data["cells_reached"]),
            share=float(data["share"]),
            axis_shares={str(k): float(v) for k, v in data["axis_shares"].items()},
            missing=tuple(data["missing"]),
            sparse=tuple(data["sparse"]),
        )

    def summary(self) -> list[str]:
        """Plain-language lines: the share reached and the directions missing."""
        lines = [
            f"Coverage: the samples reach {self.cells_reached} of {self.cells} equal-area directions "
            f"({100 * self.share:.0f} %)."
        ]
        for axis in self.missing:
            lines.append(
                f"No samples with the field along the sensor {axis} axis ({_pointing_words(axis)}): "
                f"only {100 * self.axis_shares[axis]:.0f} % of those directions were reached; turn the sensor "
                "so that this side faces the field."
            )
        for axis in self.sparse:
            lines.append(
                f"Few samples with the field along the sensor {axis} axis ({_pointing_words(axis)}): "
                f"{100 * self.axis_shares[axis]:.0f} % of those directions were reached."
            )
        return lines


def _pointing_words(axis: str) -> str:
    """Where that axis points when the field lies along it (the field dips down north of the equator)."""
    letter = axis[1]
    if axis[0] == "+":
        return f"the sensor {letter} axis pointing along the field: north and down, in the northern hemisphere"
    return f"the sensor {letter} axis pointing against the field: south and up, in the northern hemisphere"


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
        Samples the information was scaled to (all samples the fit used).
    effective_samples : float or None
        How many independent samples would give the same uncertainty: fewer than ``n_samples`` when the
        samples are correlated in time or the model misses part of the signal (batch means over the
        recording); None when the order of the samples was not known.
    """

    offset_sigma: tuple[float, float, float] | None
    scale_sigma: tuple[float, float, float] | None
    field_strength_sigma: float | None
    heading_sigma_deg: float | None
    heading_sigma_max_deg: float | None
    inclination_deg: float
    residual_sigma: float
    n_samples: int
    effective_samples: float | None = None

    def scaled(self, factor: float) -> Uncertainty:
        """Every one-sigma times ``factor`` (and the effective samples divided by its square)."""

        def times(values: tuple[float, float, float] | None) -> tuple[float, float, float] | None:
            return None if values is None else (values[0] * factor, values[1] * factor, values[2] * factor)

        def one(value: float | None) -> float | None:
            return None if value is None else value * factor

        effective = None if self.effective_samples is None else self.effective_samples / factor**2
        return Uncertainty(
            offset_sigma=times(self.offset_sigma),
            scale_sigma=times(self.scale_sigma),
            field_strength_sigma=one(self.field_strength_sigma),
            heading_sigma_deg=one(self.heading_sigma_deg),
            heading_sigma_max_deg=one(self.heading_sigma_max_deg),
            inclination_deg=self.inclination_deg,
            residual_sigma=self.residual_sigma,
            n_samples=self.n_samples,
            effective_samples=effective,
        )

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
            "effective_samples": self.effective_samples,
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
            effective_samples=number(data.get("effective_samples")),
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
            verdict = f"beyond the uncertainty: this fit is biased, prefer {option('method', 'auto')} (or ml, als)"
        return [
            f"Consistency: the maximum-likelihood fit of the same model differs by ({offset}){label} in offset"
            f"{size} and by {self.heading_difference_deg:.2g}° in level heading: {verdict}."
        ]


class Reason(str):
    """One reason of a verdict: the clause in words, with a stable machine-readable ``code``.

    A ``Reason`` *is* its words (a ``str``), so every reader that prints or joins reasons keeps working;
    code that decides reads :attr:`code` instead of the wording. Codes are listed in
    :data:`REASON_CODES` (and docs/diagnostics.md); tests assert codes, not wording.

    Parameters
    ----------
    text : str
        The clause in words, with its consequence.
    code : str
        A stable identifier (``"single_axis"``, ``"no_ellipsoid"``, ``"undetermined"``, ...).
    remedy : tuple of (str, str) pairs, optional
        What to change, as data: ``(argument, value)`` pairs (a keyword argument in Python, rendered as a
        ``--flag`` by the command line), e.g. ``(("method", "vector"),)``. Empty when the remedy is to record
        again.
    """

    code: str
    remedy: tuple[tuple[str, str], ...]

    def __new__(cls, text: str, code: str = "unclassified", remedy: tuple[tuple[str, str], ...] = ()) -> Reason:
        self = super().__new__(cls, text)
        self.code = str(code)
        self.remedy = tuple((str(name), str(value)) for name, value in remedy)
        return self

    def __reduce__(self) -> tuple[Any, ...]:
        return (Reason, (str(self), self.code, self.remedy))

    @property
    def text(self) -> str:
        return str.__str__(self)

    def to_dict(self) -> dict[str, Any]:
        data: dict[str, Any] = {"code": self.code, "text": self.text}
        if self.remedy:
            data["remedy"] = [list(pair) for pair in self.remedy]
        return data

    @classmethod
    def from_value(cls, value: Any) -> Reason:
        """A reason from its JSON form: ``{"code", "text"[, "remedy"]}``, or the bare words of schema 1."""
        if isinstance(value, Reason):
            return value
        if isinstance(value, dict):
            remedy = tuple((str(pair[0]), str(pair[1])) for pair in value.get("remedy", ()))
            return cls(str(value["text"]), str(value.get("code", "unclassified")), remedy)
        return cls(str(value))


#: A clause shorter than this is said again rather than referred to (``as the sphere model`` saves nothing).
SAID_ONCE_MIN = 30


def said_once(items: Sequence[tuple[str, str, Sequence[str]]]) -> str:
    """Each item's reasons as one line, each reason said once: ``label: r1; r2; label2: as label``.

    ``items``: (label, name, reasons), e.g. ``("the diag model", "diag", support.refusals)``; a reason may hold
    several clauses separated by ``"; "``. A clause that an earlier item gave (the item's own ``name`` aside: the
    sphere's "the sphere fit would mean nothing" is diag's "the diag fit ...") becomes ``as <that label>``, said
    once for consecutive such clauses. The refusals of several models often share their cause (too few
    directions), which a reader should read once.
    """
    out: list[str] = []
    seen: dict[str, str] = {}  # a clause with its item's name blanked -> the label that gave it first
    for label, name, given in items:
        clauses = [clause for reason in given for clause in str(reason).split("; ")]
        said: list[str] = []
        referred: str | None = None
        for clause in clauses:
            key = re.sub(rf"\b{re.escape(name)}\b", "\0", clause) if name else clause
            first = seen.get(key)
            if first is not None and first != label and len(clause) >= SAID_ONCE_MIN:
                if referred != first:
                    said.append(f"as {first}")
                referred = first
                continue
            seen.setdefault(key, label)
            said.append(clause)
            referred = None
        out.append(f"{label}: " + "; ".join(said))
    return "; ".join(out)


def reasons(values: Any, code: str = "unclassified") -> tuple[Reason, ...]:
    """Each value as a :class:`Reason` (plain words get ``code``); a Reason keeps its own code."""
    return tuple(value if isinstance(value, Reason) else Reason(str(value), code) for value in values)


class ReasonList(list[Reason]):
    """The reasons a judge collects: ``add(code, text)`` appends a :class:`Reason`."""

    def add(self, code: str, text: str, remedy: tuple[tuple[str, str], ...] = ()) -> None:
        if code not in REASON_CODES:
            raise KeyError(f"unknown reason code {code!r}: add it to REASON_CODES with its meaning")
        self.append(Reason(text, code, remedy))

    def extend_last(self, code: str, text: str) -> None:
        """Append ``text`` to the last reason's words, giving it ``code``."""
        last = self[-1]
        self[-1] = Reason(last + text, code, last.remedy)


#: The stable reason codes, each with what it means. A refusal or weakness carries one of these.
REASON_CODES: dict[str, str] = {
    "too_few_samples": "fewer samples than the model needs",
    "no_ellipsoid": "the samples lie on no ellipsoid (a cloud, a still sensor, a changing field)",
    "large_residual": "the samples lie on an ellipsoid only loosely",
    "single_axis": "the sensor turned about one axis only",
    "undetermined": "a combination of parameters is not determined by the samples",
    "weakly_determined": "a combination of parameters is weakly determined",
    "restricted_attitude": "the calibration holds only near the attitudes recorded",
    "model_inadequate": "a restricted model (sphere, axis-aligned, min/max) cannot describe the distortion",
    "field_mismatch": "the fitted field strength contradicts the known one",
    "unit_mismatch": "the fitted field strength is not the Earth's field in the declared unit",
    "biased": "the method is biased on these samples (far from the maximum-likelihood fit of its model)",
    "low_coverage": "the samples cover a small share of directions",
    "overfit": "the fit does much worse on held-out samples than on its own",
    "inconsistent_halves": "two parts of the recording give different calibrations",
    "saturated": "samples clipped at the sensor's full scale",
    "solver": "the solver did not converge",
    "lag_at_edge": "the attitude's lag lies at the edge of the search",
    "reference": "the reference field or attitude does not explain the samples",
    "accelerometer": "the accelerometer disagrees with the reference or the gyroscope",
    "gyro": "the gyroscope does not explain the magnetometer's turning",
    "inclination": "the inclination given disagrees with the samples",
    "logging_rate": "the compass was logged too slowly for the motion",
    "calibration_in_use": "the fit corrects an unknown calibration already applied",
    "vehicle_methods": "a vehicle's recording: the methods that use its attitude, gyroscope or the known field",
    "compass_misoriented": "a compass's declared orientation disagrees with the other compasses' and the attitude",
    "compasses_inconsistent": "a firmware's pre-arm check would find the compasses inconsistent",
    "compass_follows_current": "a compass's field follows the battery current or the throttle",
    "firmware_check": "a firmware's own calibration acceptance test fails on these samples",
    "motor_undetermined": "the motors' regressor does not vary independently of the attitude and the offset",
    "motor_no_regressor": "the log holds no current or throttle on the compass's stamps to fit the motors' field",
    "motor_negligible": "the motors' field is too small to matter or to tell from the noise; no term fitted",
    "motor_not_exportable": "the export format cannot hold the motors' field",
    "gyro_unit": "the gyroscope's rates fit only in another unit (degrees per second)",
    "time_unit": "the time stamps fit only in another unit (milliseconds, microseconds)",
    "gyro_axes": "the gyroscope's axes are of the other handedness than the magnetometer's (swapped or sign-flipped)",
    "field_drift": "the field strength changed along the recording and the fit follows the change",
    "motor_weak": "the motors' term kept is weakly told from the attitude: it may be off by more than its one-sigma",
    "no_location": "the World Magnetic Model needs the place: no location given and the recording holds no GNSS fix",
    "unreadable_file": "the recording cannot be read: missing, empty, damaged, cut short or in no format magfit reads",
    "bad_option": "an option the recording cannot serve (a column, unit or method it does not hold)",
    "bad_samples": "the samples are malformed (NaN or infinite values, another shape than N rows of 3)",
    "attitude_convention": "the attitude's world is upside down against the accelerometer's gravity (ENU read as NED)",
    "handedness_undetermined": "the recording does not tell the gyroscope's handedness against the magnetometer's",
    "mag_handedness": "the magnetometer's axes are left-handed against the gyroscope's: its field comes out reversed",
    "unclassified": "a reason without a code of its own yet",
}


@dataclass(frozen=True)
class Support:
    """The verdict on a calibration: do the samples determine it? (see :mod:`magfit.diagnostics.verdict`)

    Attributes
    ----------
    verdict : {"supported", "weak", "refused"}
        ``"refused"`` calibrations are not returned by :func:`magfit.fit` unless forced.
    refusals : tuple of Reason
        Why the samples do not support the calibration, each a clause in words with its code.
    weaknesses : tuple of Reason
        What is weakly determined or suspicious, each a clause with its consequence and its code.
    advice : str
        What to record instead.
    forced : bool
        True when the calibration was returned although refused (``allow_undetermined=True``, ``--force``).
    """

    verdict: Literal["supported", "weak", "refused"]
    refusals: tuple[Reason, ...]
    weaknesses: tuple[Reason, ...]
    advice: str
    forced: bool = False

    def __post_init__(self) -> None:
        if self.verdict not in ("supported", "weak", "refused"):
            raise ValueError(f"a verdict is supported, weak or refused, not {self.verdict!r}")
        object.__setattr__(self, "refusals", reasons(self.refusals))
        object.__setattr__(self, "weaknesses", reasons(self.weaknesses))

    @classmethod
    def judged(cls, refusals: Iterable[Reason], weaknesses: Iterable[Reason], advice: str) -> Support:
        """The verdict that follows from the reasons: refused if any refusal, weak if any weakness, else supported."""
        refused, weak = tuple(refusals), tuple(weaknesses)
        verdict: Literal["supported", "weak", "refused"] = "refused" if refused else "weak" if weak else "supported"
        return cls(verdict=verdict, refusals=refused, weaknesses=weak, advice=advice)

    @property
    def codes(self) -> tuple[str, ...]:
        """The codes of the refusals, then of the weaknesses, in order, each once."""
        return tuple(dict.fromkeys(reason.code for reason in (*self.refusals, *self.weaknesses)))

    @property
    def warnings(self) -> tuple[str, ...]:
        """What a user must read before trusting the calibration: refusals (when forced) then weaknesses."""
        forced = tuple(
            Reason(f"NOT SUPPORTED (forced): {reason}", reason.code, reason.remedy) for reason in self.refusals
        )
        return forced + self.weaknesses

    def message(self, method: str) -> str:
        """The one-line refusal: the method, every reason, and what to record."""
        return f"the samples do not support the {method} calibration: " + "; ".join(self.refusals) + f"; {self.advice}"

    def to_dict(self) -> dict[str, Any]:
        return {
            "verdict": self.verdict,
            "refusals": [str(r) for r in self.refusals],
            "weaknesses": [str(w) for w in self.weaknesses],
            "refusal_codes": [r.code for r in self.refusals],
            "weakness_codes": [w.code for w in self.weaknesses],
            "advice": self.advice,
            "forced": self.forced,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Support:
        def read(texts: Any, codes: Any) -> tuple[Reason, ...]:
            texts = list(texts)
            codes = list(codes) if codes is not None else []
            codes = [str(c) for c in codes] + ["unclassified"] * (len(texts) - len(codes))
            pairs = zip(texts, codes, strict=True)
            return tuple(Reason.from_value(t) if isinstance(t, dict) else Reason(str(t), c) for t, c in pairs)

        verdict = str(data["verdict"])
        if verdict not in ("supported", "weak", "refused"):
            raise ValueError(f"a verdict is supported, weak or refused, not {verdict!r}")
        return cls(
            verdict=verdict,  # type: ignore[arg-type]
            refusals=read(data["refusals"], data.get("refusal_codes")),
            weaknesses=read(data["weaknesses"], data.get("weakness_codes")),
            advice=str(data["advice"]),
            forced=bool(data.get("forced", False)),
        )

    def summary(self) -> list[str]:
        words = _VERDICT_WORDS.get(self.verdict, self.verdict)
        return [f"Verdict: {words}{' (returned because forced)' if self.forced else ''}."]


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
    unit : str or None
        The samples' unit, for the summary.
    support : Support or None
        The verdict (see :mod:`magfit.diagnostics.verdict`); ``warnings`` are its refusals (when forced) and
        weaknesses.
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
    support: Support | None = None

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
            "support": None if self.support is None else self.support.to_dict(),
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
                support=None if data.get("support") is None else Support.from_dict(data["support"]),
            )
        except (KeyError, TypeError) as error:
            raise MagfitError(f"diagnostics are malformed: {error}") from None

    def summary(self) -> list[str]:
        """Plain-language lines, warnings first."""
        lines = [f"WARNING: {warning}" for warning in self.warnings]
        if self.support is not None:
            lines.extend(self.support.summary())
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
