"""Level turns with the field strength given: a sphere of known radius through a circle of samples has its centre
on either side of the circle's plane, so the offset along the turning axis has two values. The refusal names both
(one of them the truth's) and the vehicle advice does not send the user to the pinned sphere."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

import magfit
from magfit.pipeline.advice import level_only, vehicle_advice

TRUTH = np.array([10.0, -5.0, 20.0])


def _level(seed: int, tilt_deg: float = 0.0) -> magfit.Simulation:
    orientations = "yaw" if tilt_deg == 0.0 else "restricted"
    return magfit.simulate(
        1500, hard_iron=TRUTH, field_strength=50.0, inclination_deg=60, noise=0.3, orientations=orientations,
        max_tilt_deg=tilt_deg or 10.0, seed=seed,
    )  # fmt: skip


def _offsets_named(message: str) -> list[np.ndarray]:
    groups = re.findall(r"\(([-\d.e]+(?:, [-\d.e]+){2})\)", message)
    return [np.array([float(v) for v in group.split(",")]) for group in groups]


@pytest.mark.parametrize("seed", [1, 2])
def test_the_pinned_sphere_on_level_turns_names_both_offsets(seed: int) -> None:
    sim = _level(seed)
    with pytest.raises(magfit.CalibrationError) as refused:
        magfit.fit(sim.samples, method="sphere", field_strength=50.0)
    assert "single_axis" in refused.value.codes
    named = _offsets_named(str(refused.value))
    assert len(named) == 2, str(refused.value)
    # Ground truth: one of the two is the simulated offset; the other its mirror across the circle's plane, where
    # the field's vertical part (50 sin 60° ≈ 43.3) changes sign.
    errors = sorted(float(np.max(np.abs(offset - TRUTH))) for offset in named)
    assert errors[0] < 0.3 and abs(errors[1] - 2 * 50 * np.sin(np.radians(60))) < 1.0, named


def test_a_level_samples_file_refusal_names_both_offsets_and_no_pinned_sphere(tmp_path: Path) -> None:
    sim = _level(1)
    path = tmp_path / "level.csv"
    np.savetxt(path, sim.samples, fmt="%.6f", delimiter=",", header="mx,my,mz", comments="")
    with pytest.raises(magfit.CalibrationError) as refused:
        magfit.calibrate_file(path, "sphere", unit="uT", field_strength=50.0)
    text = getattr(refused.value, "text", str(refused.value))
    named = _offsets_named(text)
    assert len(named) == 2 and min(float(np.max(np.abs(o - TRUTH))) for o in named) < 0.3, text


def test_the_circle_is_told_from_a_banked_flight() -> None:
    assert level_only(np.cov(_level(1).samples.T))
    assert not level_only(np.cov(_level(1, tilt_deg=15.0).samples.T))
    level = vehicle_advice(Path("level.csv"), is_log=False, streams=(), unit="uT", method="auto", level=True)
    banked = vehicle_advice(Path("level.csv"), is_log=False, streams=(), unit="uT", method="auto")
    assert [dict(reason.remedy)["method"] for reason in level] == ["vector", "gyro"]
    assert [dict(reason.remedy)["method"] for reason in banked] == ["vector", "gyro", "sphere"]
