"""Calibrations saved with schema version 1 (their facts in ``details``) still load, as typed fields.

The files under tests/data/v1 were written by magfit at commit b4f781f (before schema version 2), from
simulated samples with a known offset and soft iron (tests/data/v1/README)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import magfit
from magfit.diagnostics import model_kind

V1 = Path(__file__).parent / "data" / "v1"
TRUE_OFFSET = np.array([12.0, -7.0, 3.0])


def _load(name: str) -> tuple[magfit.Calibration, dict]:
    text = (V1 / f"{name}.json").read_text()
    return magfit.Calibration.from_json(text), json.loads(text)


@pytest.mark.parametrize("name", ["auto_robust", "ellipsoid_known", "ml", "robust", "sphere_known_diagnostics"])
def test_a_version_1_file_loads_with_its_verdict_and_options_typed(name: str) -> None:
    calibration, raw = _load(name)
    assert raw["schema_version"] == 1
    assert calibration.support is not None and calibration.support.verdict == raw["details"]["support"]["verdict"]
    assert calibration.support.codes == tuple(
        dict.fromkeys(raw["details"]["support"]["refusal_codes"] + raw["details"]["support"]["weakness_codes"])
    )
    assert dict(calibration.options) == raw["details"]["options"]
    assert "support" not in calibration.details and "options" not in calibration.details
    # written again, it is version 2, and reads back equal
    again = magfit.Calibration.from_json(calibration.to_json())
    assert json.loads(calibration.to_json())["schema_version"] == 2 and again == calibration


def test_version_1_robust_facts_become_the_rejected_record() -> None:
    for name in ("robust", "auto_robust"):
        calibration, raw = _load(name)
        assert calibration.rejected is not None
        assert calibration.rejected.count == raw["details"]["n_rejected"] >= 30  # the 30 spikes written in
        assert [list(run) for run in calibration.rejected.runs] == raw["details"]["rejected"]["runs"]
        np.testing.assert_allclose(calibration.offset, TRUE_OFFSET, atol=0.2)  # against the simulated truth
    robust, raw = _load("robust")
    assert robust.rejected is not None and robust.rejected.threshold == raw["details"]["threshold"]
    assert robust.solver is not None and robust.solver.converged is raw["details"]["converged"]


def test_version_1_auto_known_field_and_solver_facts() -> None:
    auto, raw = _load("auto_robust")
    assert auto.auto is not None and auto.auto.model == raw["details"]["chosen_model"]
    assert auto.auto.chosen == raw["details"]["chosen"] and auto.auto.reason == raw["details"]["reason"]
    assert auto.model is None and model_kind(auto) == raw["details"]["chosen_model"]  # inferred: version 1 only
    known, raw = _load("ellipsoid_known")
    assert known.known_field is not None and known.known_field.fitted == raw["details"]["fitted_field_strength"]
    assert known.field_strength == 48.0 and not known.known_field.pinned
    pinned, _ = _load("sphere_known_diagnostics")
    assert pinned.known_field is not None and pinned.known_field.pinned and pinned.diagnostics is not None
    ml, raw = _load("ml")
    assert ml.solver is not None and ml.solver.converged is True
    assert ml.solver.iterations == raw["details"]["iterations"]
    assert ml.details["covariance"] == raw["details"]["covariance"]  # free-form extras stay in details


def test_version_2_writes_the_facts_beside_details_and_refuses_them_in_a_version_1_file() -> None:
    sim = magfit.simulate(2000, hard_iron=TRUE_OFFSET, field_strength=48.0, noise=0.3, seed=5)
    calibration = magfit.fit(sim.samples, "sphere", field_strength=48.0)
    data = calibration.to_dict()
    assert data["support"]["verdict"] == "supported" and data["model"] == "sphere"
    assert data["known_field"]["pinned"] is True and data["options"] == {"field_strength": 48.0}
    assert "support" not in data["details"]
    np.testing.assert_allclose(calibration.offset, TRUE_OFFSET, atol=0.05)
    with pytest.raises(magfit.DataFileError, match="version 1 keeps its facts in 'details'"):
        magfit.Calibration.from_dict({**data, "schema_version": 1})
    with pytest.raises(magfit.DataFileError, match="malformed"):
        magfit.Calibration.from_dict({**data, "support": {"verdict": "maybe"}})
    with pytest.raises(magfit.DataFileError, match="malformed"):
        magfit.Calibration.from_dict({**data, "model": "banana"})
    with pytest.raises(magfit.DataFileError, match="beyond the range of float64"):
        magfit.Calibration.from_json(calibration.to_json().replace('"pinned": true', '"pinned": true, "x": 1e999'))


def test_version_1_vehicle_fits_become_their_family_records() -> None:
    vector, raw = _load("vector")
    assert vector.frame == "vehicle" and vector.model == "vehicle" and vector.vector is not None
    assert vector.vector.lag_s == raw["details"]["lag_s"] and vector.vector.lag_sigma_s == raw["details"]["lag_sigma_s"]
    assert vector.vector.alignment_sigma_deg == raw["details"]["alignment_sigma_deg"]
    assert vector.support is not None and vector.support.verdict == "weak" and vector.diagnostics is not None
    gyro, raw = _load("gyro")
    assert gyro.gyro is not None and gyro.gyro.mapping == raw["details"]["mapping"] == "+x+y+z"  # the simulated axes
    np.testing.assert_allclose(gyro.gyro.bias, raw["details"]["gyro_bias"])
    assert gyro.gyro.sensor_matrix is not None and np.shape(gyro.gyro.sensor_matrix) == (3, 3)
    assert gyro.solver is not None and gyro.solver.iterations == raw["details"]["solver"]["iterations"]
    for calibration in (vector, gyro):
        assert magfit.Calibration.from_json(calibration.to_json()) == calibration
