"""A motors' field that is large but cannot be fitted (its current follows the attitude) is said as a weakness of the
calibration, with its size and the heading it can turn; a clean vehicle gets no such weakness."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import magfit
from magfit.findings import Reason
from magfit.motor import MIN_PERCENT, MotorFit
from magfit.motorsim import simulate_motor_flight
from magfit.motorterm import MotorTerm
from magfit.pipeline.motor import left_in
from magfit.pipeline.motor import weakly_told as weakly_told_reason
from test_motor_logs import write_flight


def _fit(percent: float, sigma: float, code: str = "motor_undetermined", fitted: bool = False) -> MotorFit:
    truth = simulate_motor_flight(5, driver="none", seed=1).truth
    term = MotorTerm("current", np.array([3.0, 0.0, 0.0]), lag_s=0.0, full_scale=30.0)
    return MotorFit(truth, fitted, term, percent, sigma, 0.01, (9.0, 8.0), (Reason("not fitted", code),))


def test_left_in_names_a_large_undetermined_term_with_its_heading() -> None:
    reason = left_in([_fit(16.0, 2.0)])
    assert reason is not None and reason.code == "motor_undetermined"
    assert "9°" in reason  # atan(0.16): the heading an error of 16 % of the field turns where it is horizontal


@pytest.mark.parametrize(
    ("fit", "why"),
    [
        (_fit(MIN_PERCENT + 1.0, 1.0), "within two one-sigmas of the limit"),
        (_fit(16.0, 2.0, code="motor_negligible"), "not the undetermined case"),
        (_fit(16.0, 2.0, fitted=True), "fitted: nothing left in"),
    ],
)
def test_left_in_says_nothing_otherwise(fit: MotorFit, why: str) -> None:
    assert left_in([fit]) is None, why


def _flight_whose_current_follows_the_attitude(per_unit: float) -> magfit.motorsim.MotorFlight:
    clean = simulate_motor_flight(240, driver="none", seed=11)
    body = np.einsum("nji,j->ni", clean.attitude, clean.field_ned)
    current = 5.0 + 20.0 * (1.0 + body[:, 0] / np.linalg.norm(clean.field_ned))  # a function of the heading
    k = per_unit * np.array([0.6, -0.64, 0.48])
    return replace(clean, samples=clean.samples + np.outer(current, k), current=current)


def test_calibrate_file_says_the_motors_field_it_leaves_in(tmp_path: Path) -> None:
    flight = _flight_whose_current_follows_the_attitude(3.0)  # 135 mG at 45 A: about 27 % of the field
    log = write_flight(tmp_path / "follows.bin", flight, ctun=False)
    try:
        result = magfit.calibrate_file(log, motor="auto")
    except magfit.MagfitError as error:  # refused outright is acceptable too, never silently supported
        assert error.codes
        return
    support = result.calibration.support
    assert result.calibration.motor is None
    assert "motor_undetermined" in support.codes and support.verdict != "supported"
    said = next(w for w in support.weaknesses if w.code == "motor_undetermined")
    printed = result.calibration.details.get("diagnostics", {}).get("warnings", [])
    assert str(said) in printed  # the command line prints these with the verdict's count


def test_a_clean_vehicle_gets_no_left_in_weakness(tmp_path: Path) -> None:
    log = write_flight(tmp_path / "clean.bin", simulate_motor_flight(240, driver="none", seed=11), ctun=False)
    result = magfit.calibrate_file(log, motor="auto")
    assert "motor_undetermined" not in result.calibration.support.codes


def test_a_kept_term_weakly_told_from_the_attitude_is_a_weakness() -> None:
    weak = replace(_fit(4.2, 1.0, fitted=True), independence=0.025)
    reason = weakly_told_reason(weak)
    assert reason is not None and reason.code == "motor_weak"
    assert weakly_told_reason(replace(weak, independence=0.5)) is None  # well told: nothing to say
    assert weakly_told_reason(replace(weak, fitted=False)) is None  # not kept: left_in's business
