"""The default fit of a vehicle's recording: when the magnitude-only fit (``auto``) refuses it, the methods that
use the vehicle's other streams, on the streams the recording holds.

A vehicle that drives or sails level turns its compass about one axis: the field's magnitude then pins the
offsets across that axis and leaves the rest undetermined (docs/methods.md, "Which method?"), and ``auto``
refuses. The recording often holds what pins the rest: the attitude with the reference field (``vector``: the
field expected at each sample, in direction too) or the gyroscope (``gyro``: the field's rotation between
samples). :func:`calibrate_file` called without a method (``magfit calibrate`` without ``--method``) fits those
the recording holds (:func:`held_by_samples_file`; a log: those its streams serve), each judged by its own
verdict, and returns the best-determined one (:func:`best`: a supported fit before a weak one, then the smallest
level-heading one-sigma), saying which and why in a note (:func:`rescue_note`). When every one refuses too, the
refusal says what each found (:func:`refusal`).

An explicit method, ``auto`` included, is that method alone.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

from ..errors import CalibrationError, DataFileError, MagfitError, OptionError
from ..findings import Reason
from .advice import RefusedWithAdvice, StreamsMissing
from .results import CompassCalibration

__all__ = ["VEHICLE_METHODS", "Attempt", "attempt_all", "best", "held_by_samples_file", "refusal", "rescue_note"]

#: The methods tried, in this order, when the default's magnitude-only fit refuses a vehicle's recording.
VEHICLE_METHODS = ("vector", "gyro")

#: What each method reads beyond the samples, in words.
_READS = {"vector": "attitude with the reference field", "gyro": "gyroscope and time"}


@dataclass(frozen=True)
class Attempt:
    """One vehicle method tried: its fit, or why it could not be made; the notes it gave."""

    method: str
    compass: CompassCalibration | None = None
    error: MagfitError | None = None
    notes: tuple[str, ...] = ()

    @property
    def heading_sigma_deg(self) -> float:
        """The fit's level-heading one-sigma (degrees); infinite when it states none or refused."""
        if self.compass is None:
            return float("inf")
        diagnostics = self.compass.calibration.diagnostics
        sigma = diagnostics.uncertainty.heading_sigma_deg if diagnostics and diagnostics.uncertainty else None
        return float(sigma) if sigma is not None else float("inf")

    @property
    def verdict(self) -> str | None:
        """The fit's support verdict (``supported``, ``weak``), None when refused."""
        if self.compass is None:
            return None
        support = self.compass.calibration.support
        return support.verdict if support is not None else "supported"

    def found(self) -> str:
        """What the attempt found, in words (one clause)."""
        if self.compass is not None:
            return f"{self.method} fits it ({self.verdict}, level heading one-sigma ±{self.heading_sigma_deg:.2g}°)"
        error = self.error
        text = error.text if isinstance(error, RefusedWithAdvice | StreamsMissing) else str(error)
        return f"{self.method} ({_READS[self.method]}): {text}"


def held_by_samples_file(path: Path, given: Sequence[str], location_given: bool) -> tuple[str, ...]:
    """The vehicle methods a samples file's streams serve, from its header alone (no pass over the file): the
    columns its names give (:func:`magfit.io.streams.find_stream_columns`) and those named by the caller
    (``given``: ``attitude``, ``reference``, ``gyro``, ``time``). ``vector`` needs the attitude and the reference
    field (its columns, the file's latitude and longitude or the place given); ``gyro`` the gyroscope and the
    time."""
    from ..io.layout import sniff
    from ..io.streams import find_stream_columns

    try:
        header = sniff(path).header
    except MagfitError:
        return ()
    held = set(find_stream_columns(header)) if header is not None else set()
    held |= set(given)
    methods = []
    if "attitude" in held and ({"reference", "place"} & held or location_given):
        methods.append("vector")
    if {"gyro", "time"} <= held:
        methods.append("gyro")
    return tuple(methods)


def attempt_all(
    methods: Sequence[str], fit_one: Callable[[str, Callable[[str], None]], CompassCalibration]
) -> list[Attempt]:
    """Each method of ``methods`` fitted by ``fit_one(method, notify)``; a refusal, a missing stream or an
    unusable one recorded as the attempt's error."""
    attempts = []
    for method in methods:
        notes: list[str] = []
        try:
            compass = fit_one(method, notes.append)
        except (CalibrationError, OptionError, DataFileError) as error:
            attempts.append(Attempt(method, error=error, notes=tuple(notes)))
            continue
        attempts.append(Attempt(method, compass=compass, notes=tuple(notes)))
    return attempts


def best(attempts: Sequence[Attempt]) -> Attempt | None:
    """The best-determined fit: a supported one before a weak one, then the smallest level-heading one-sigma;
    None when every attempt refused."""
    fitted = [a for a in attempts if a.compass is not None and a.verdict in ("supported", "weak")]
    if not fitted:
        return None
    return min(fitted, key=lambda a: (a.verdict != "supported", a.heading_sigma_deg))


def rescue_note(where: str, refused: CalibrationError, attempts: Sequence[Attempt], chosen: Attempt) -> str:
    """The note of a rescued default fit: which method, why the magnitude-only fit was not enough, and what
    each method tried found."""
    from ..findings import REASON_CODES
    from ..remedy import option

    why = "; ".join(f"{code}: {REASON_CODES.get(code, code)}" for code in refused.codes) or "refused"
    others = "; ".join(a.found() for a in attempts if a is not chosen)
    return (
        f"{where}: the magnitude-only fit ({option('method', 'auto')}) cannot calibrate this recording ({why}): "
        "the field's magnitude alone does not fix it from turns about one axis mostly, as a vehicle makes; what "
        f"the recording also holds ({_READS[chosen.method]}) does: calibrated by the {chosen.method} method "
        f"({chosen.verdict}, level heading one-sigma ±{chosen.heading_sigma_deg:.2g}°, the best determined of "
        "those tried)" + (f"; also tried: {others}" if others else "")
    )


def with_rescue(compass: CompassCalibration, note: str) -> CompassCalibration:
    """``compass`` with the rescue's note first among its notes."""
    return replace(compass, notes=(note, *compass.notes))


def refusal(error: CalibrationError, attempts: Sequence[Attempt]) -> CalibrationError:
    """The default's refusal when the vehicle methods refuse too: the magnitude-only fit's reason, then what
    each method found, with every code; the advice kept for the methods not tried."""
    if not attempts:
        return error
    tried = "; ".join(a.found() for a in attempts)
    codes = tuple(dict.fromkeys((*error.codes, *(c for a in attempts if a.error for c in a.error.codes))))
    if isinstance(error, RefusedWithAdvice):
        names = {a.method for a in attempts}
        advice: tuple[Reason, ...] = tuple(
            reason for reason in error.advice if dict(reason.remedy).get("method") not in names
        )
        text = f"{error.text}; the recording's own streams were tried too: {tried}"
        return RefusedWithAdvice(error.path, text, advice, codes=codes)
    # The magnitude-only fit's general words ("on a vehicle, ... --method vector ... --method gyro") would name
    # the methods just tried: what each of them found replaces them.
    message = f"{error.without_general_advice()}; the recording's own streams were tried too: {tried}"
    return CalibrationError(message, codes=codes, remedy=error.remedy)
