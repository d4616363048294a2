"""The one verdict step: a calibration judged is refused (raised, with its codes) or returned with its verdict.

Every path that returns a calibration reaches a :class:`~magfit.findings.Support` by its own judge (the
magnitude-only one, :func:`magfit.diagnostics.verdict.judge`; the reference field's,
:mod:`magfit.diagnostics.reference`; the rotation kinematics' of the gyro-aided fit) and then comes here:
:func:`settle` raises a refusal as :class:`~magfit.errors.CalibrationError` carrying the reasons' codes, or,
forced (``allow_undetermined``, ``--force``), returns the calibration marked forced with the refusal first
among its warnings; a weak verdict is returned with its weaknesses. :func:`with_reasons` adds a method's own
reasons before that step, and :func:`starting_weakness` is the alignment's cap: an alignment is no better
supported than the calibration it starts from.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import replace

from ..calibration import Calibration
from ..errors import CalibrationError
from ..findings import Diagnostics, Reason, Support
from ..remedy import option

__all__ = ["settle", "starting_weakness", "with_reasons"]


def with_reasons(support: Support, refusals: Iterable[Reason] = (), weaknesses: Iterable[Reason] = ()) -> Support:
    """``support`` judged again with more reasons: ``refusals`` first among its refusals, ``weaknesses`` last."""
    refusals, weaknesses = tuple(refusals), tuple(weaknesses)
    if not refusals and not weaknesses:
        return support
    return Support.judged((*refusals, *support.refusals), (*support.weaknesses, *weaknesses), support.advice)


def settle(
    calibration: Calibration,
    support: Support,
    *,
    method: str | None = None,
    allow_undetermined: bool = False,
    report: Diagnostics | None = None,
) -> Calibration:
    """``calibration`` with its verdict, or the refusal raised.

    Parameters
    ----------
    calibration : Calibration
        What the method returned.
    support : Support
        The verdict its judge reached.
    method : str, optional
        The method named in a refusal (default ``calibration.method``).
    allow_undetermined : bool
        Return a refused calibration marked ``forced`` (its refusals then open its warnings) instead of raising.
    report : Diagnostics, optional
        The diagnosis behind the verdict: attached as ``details["diagnostics"]`` (read typed with
        ``calibration.diagnostics``), with the verdict and warnings settled here.

    Raises
    ------
    CalibrationError
        The verdict is ``"refused"`` and ``allow_undetermined`` is false; ``codes`` are the reasons' codes.
    """
    if support.verdict == "refused":
        if not allow_undetermined:
            raise CalibrationError(support.message(method or calibration.method), codes=support.codes)
        support = replace(support, forced=True)
    details = dict(calibration.details)
    if report is not None:
        details["diagnostics"] = replace(report, support=support, warnings=support.warnings).to_dict()
    return replace(calibration, support=support, details=details)


def starting_weakness(starting: Calibration) -> Reason | None:
    """The alignment's cap: the weakness an alignment inherits from the calibration it starts from, or None.

    The alignment's one-sigma counts the dip angles' scatter, not an error of the calibrated field's vertical
    part, which turns every dip alike (simulated car, ``auto``'s weak calibration: 5.0° off where the alignment
    alone said supported ±0.9°). A weak or forced calibration makes the alignment weak at best.
    """
    support = starting.support
    if support is None or support.verdict == "supported":
        return None
    first = (*support.refusals, *support.weaknesses)
    said = "is weak" if support.verdict == "weak" else "was refused by its samples (forced)"
    return Reason(
        f"the calibration it starts from ({starting.method}) {said}"
        + (f" ({first[0]})" if first else "")
        + ": its error in the field's vertical part turns the dip angles, which the one-sigma above does not "
        f"count; calibrate with a tumble first and give it with {option('calibration', 'cal.json')}",
        first[0].code if first else "weakly_determined",
    )
