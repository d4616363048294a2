"""calibrate_file compares the World Magnetic Model's field with the fitted one: a Python caller gets it typed."""

from __future__ import annotations

import numpy as np
import pytest

import magfit

pytest.importorskip("pygeomag", reason="the wmm extra is not installed")

ZURICH = (47.4, 8.5, 0.4)


def _file(tmp_path, strength: float):  # type: ignore[no-untyped-def]
    sim = magfit.simulate(3000, hard_iron=[3.0, -2.0, 1.0], field_strength=strength, noise=0.002 * strength, seed=4)
    path = tmp_path / f"field{strength:g}.csv"
    np.savetxt(path, sim.samples, delimiter=",", header="mx,my,mz", comments="")
    return path


def test_a_fitted_field_far_from_the_model_is_a_coded_reason_on_the_result(tmp_path) -> None:  # type: ignore[no-untyped-def]
    agreeing = magfit.calibrate_file(_file(tmp_path, 48.0), "sphere", unit="uT", location=ZURICH, date="2026-01-01")
    model = agreeing.compasses[0].model_field
    assert model is not None and model.field.total_in("uT") == pytest.approx(48.0, rel=0.05)
    assert model.mismatch is None
    # The same sensor's samples said to be in µT but twice the model's field (steel nearby, a wrong gain).
    doubled = magfit.calibrate_file(_file(tmp_path, 96.0), "sphere", unit="uT", location=ZURICH, date="2026-01-01")
    compass = doubled.compasses[0]
    assert compass.calibration.field_strength == pytest.approx(96.0, rel=0.01)  # the simulated truth
    assert compass.model_field is not None and compass.model_field.mismatch is not None
    assert compass.model_field.mismatch.code == "field_mismatch"
    # Counts carry no physical unit: nothing to compare.
    counts = magfit.calibrate_file(_file(tmp_path, 96.0), "sphere", unit="counts", location=ZURICH, date="2026-01-01")
    assert counts.compasses[0].model_field is not None and counts.compasses[0].model_field.mismatch is None
