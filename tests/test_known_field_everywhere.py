"""The known-field option through every path: auto, robust, the pinned sphere's sanity checks, the CLI."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import magfit
from magfit import CalibrationError
from magfit.cli import cli

FIELD = 50.0  # µT


def tilted_only(max_tilt_deg: float, seed: int = 0) -> magfit.Simulation:
    """A vehicle that cannot turn over: full yaw, roll and pitch within ±max_tilt_deg."""
    return magfit.simulate(
        1000, field_strength=FIELD, hard_iron=[10.0, -20.0, 30.0], noise=1.0,
        orientations="restricted", max_tilt_deg=max_tilt_deg, seed=seed,
    )  # fmt: skip


@pytest.mark.parametrize("method", ["auto", "robust"])
@pytest.mark.slow
def test_auto_and_robust_scale_to_the_given_field(method: str) -> None:
    sim = magfit.scenario("ellipse2a", "smartphone").simulate(2000, seed=1)
    free = magfit.fit(sim.samples, method=method)
    known = 0.95 * free.field_strength  # a model's field, 5 % from what the samples show: accepted
    given = magfit.fit(sim.samples, method=method, field_strength=known)
    assert given.field_strength == known
    np.testing.assert_allclose(np.linalg.norm(given.apply(sim.samples), axis=1).mean(), known, rtol=0.01)
    assert given.known_field is not None
    assert given.known_field.fitted == pytest.approx(free.field_strength)
    np.testing.assert_allclose(given.offset, free.offset)  # the ellipsoid itself is unchanged


def test_pinned_sphere_places_the_offset_when_the_vehicle_barely_tilts() -> None:
    # ±5° of tilt: the samples outline no ellipsoid, the free fit refuses; the known radius is enough.
    sim = tilted_only(5.0)
    with pytest.raises(CalibrationError, match="biased|do not determine|only turned about"):
        magfit.fit(sim.samples, method="sphere")
    cal = magfit.fit(sim.samples, method="sphere", field_strength=FIELD)
    # noise 1 µT on 1000 samples: the offset to a fraction of a µT
    assert np.linalg.norm(cal.offset - sim.truth.offset) < 0.5


def test_pinned_sphere_beats_the_free_fit_with_little_tilt() -> None:
    sim = tilted_only(20.0, seed=3)
    free = magfit.fit(sim.samples, method="sphere")
    pinned = magfit.fit(sim.samples, method="sphere", field_strength=FIELD)
    assert np.linalg.norm(pinned.offset - sim.truth.offset) < 0.3 * np.linalg.norm(free.offset - sim.truth.offset)


def test_a_field_in_the_wrong_unit_is_refused() -> None:
    sim = magfit.simulate(1000, field_strength=FIELD, hard_iron=[10.0, -20.0, 30.0], noise=1.0, seed=2)
    with pytest.raises(CalibrationError, match="moves the centre .* check that it is in the samples' unit"):
        magfit.fit(sim.samples, method="sphere", field_strength=10 * FIELD)  # mG given for µT samples
    with pytest.raises(CalibrationError, match="lie 5.* from the best centre, not at the given field strength 30"):
        magfit.fit(sim.samples, method="sphere", field_strength=30.0)


def test_cli_field_strength(tmp_path: Path) -> None:
    sim = magfit.simulate(500, field_strength=FIELD, hard_iron=[10.0, -20.0, 30.0], noise=0.5, seed=4)
    path = tmp_path / "mag.csv"
    np.savetxt(path, sim.samples, delimiter=",", header="mx,my,mz", comments="")
    runner = CliRunner()
    result = runner.invoke(cli, ["calibrate", str(path), "--field-strength", "48", "-o", str(tmp_path / "c.json")])
    assert result.exit_code == 0, result.output
    cal = magfit.Calibration.from_json((tmp_path / "c.json").read_text())
    assert cal.field_strength == 48.0 and cal.known_field is not None
    refused = runner.invoke(cli, ["calibrate", str(path), "--field-strength", "48", "-m", "minmax"])
    assert refused.exit_code == 2
    assert "method 'minmax' has no option 'field_strength'" in refused.output
