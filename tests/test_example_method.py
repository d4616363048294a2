"""The example method of docs/ARCHITECTURE.md ("Adding a method"), run as written there, fits simulated truth."""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

import magfit
from magfit.methods import METHODS

ARCHITECTURE = Path(__file__).parents[1] / "docs" / "ARCHITECTURE.md"


def _example() -> str:
    section = ARCHITECTURE.read_text(encoding="utf-8").split("## Adding a method", 1)[1]
    (block,) = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    return block


@pytest.fixture
def midrange() -> Iterator[None]:
    assert "midrange" not in METHODS
    exec(compile(_example(), str(ARCHITECTURE), "exec"), {"__name__": "example_method"})
    try:
        yield
    finally:
        del METHODS["midrange"]  # registered for this test only: other tests list every method


def test_the_documented_method_registers_and_fits_the_simulated_offset(midrange: None) -> None:
    offset = np.array([21.0, -13.0, 8.0])
    sim = magfit.simulate(4000, hard_iron=offset, field_strength=50.0, noise=0.2, seed=11)
    calibration = magfit.fit(sim.samples, "midrange")
    assert calibration.method == "midrange" and calibration.model == "sphere"
    np.testing.assert_allclose(calibration.offset, offset, atol=0.5)  # the range's centre: within the noise
    assert calibration.field_strength == pytest.approx(50.0, rel=0.02)
    # The range's ends are single noisy samples: the verdict compares with the maximum-likelihood sphere and says
    # the method is biased (weak, about 0.2° of heading here), as it would of any method.
    assert calibration.support is not None and calibration.support.codes == ("biased",)
    assert dict(calibration.options) == {"field_strength": None}
    # the same entry serves the statistics, a refit, and a known field strength
    from_statistics = magfit.fit(magfit.Statistics.from_samples(sim.samples), "midrange")
    assert from_statistics.offset == pytest.approx(calibration.offset)
    assert magfit.refit(calibration, sim.samples[::2]).method == "midrange"
    assert magfit.fit(sim.samples, "midrange", field_strength=50.0).field_strength == 50.0


def test_the_documented_method_is_judged_like_any_other(midrange: None) -> None:
    # Soft iron the sphere cannot hold: the verdict refuses it, with a code, whoever wrote the method.
    sim = magfit.simulate(4000, soft_iron=np.diag([1.3, 0.8, 1.0]), hard_iron=[5.0, 0.0, 0.0], noise=0.01, seed=2)
    with pytest.raises(magfit.CalibrationError) as refused:
        magfit.fit(sim.samples, "midrange")
    assert "model_inadequate" in refused.value.codes
