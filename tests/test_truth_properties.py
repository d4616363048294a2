"""Every returned calibration is within its stated uncertainty of the simulated truth, or refused.

The kinds of data the second fuzz campaign found weak-but-wrong or supported-but-wrong fits on
(``benchmarks/campaign.py``: clipped at full scale, half a sphere with soft iron, clusters of attitudes,
tilt cones, coarse integer counts, level flight), each with a known truth. For every magnitude-only
method, a fit that comes back "supported" or "weak" must have a true level-heading error within
``campaign.COVER`` (3) times its stated heading one-sigma (or below ``campaign.FLOOR_DEG``, 0.1°).
The seed of a failing trial is in the assertion message (and hypothesis prints how to replay it).
"""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import magfit

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
campaign = importlib.import_module("campaign")


def _check(kind: str, seed: int, methods: tuple[str, ...] = campaign.METHODS) -> None:
    sim, samples = campaign.trial(kind, seed)
    for method in methods:
        outcome = campaign.score(kind, seed, method, sim, samples)
        assert not outcome.exceeds, (
            f"{kind}, seed {seed}, {method}: {outcome.verdict} {outcome.codes}, true heading error "
            f"{outcome.error_deg:.3g}° against a stated one-sigma of ±{outcome.stated_deg}° "
            f"(rerun: python benchmarks/campaign.py --kinds '{kind}' --methods {method} --seed {seed} --trials 1)"
        )


@pytest.mark.parametrize(("kind", "seed"), [("hemisphere", 0), ("saturated", 1)])
def test_the_campaign_reproducers_are_refused_or_covered(kind: str, seed: int) -> None:
    # Before: a sphere on half a sphere with soft iron came back weak 5.8° off stating ±0.47°; diag and sphere on
    # a clipped sensor 4.8-6.8° off stating ±0.2-0.4°.
    _check(kind, seed, ("sphere", "diag", "minmax", "ellipsoid"))


@pytest.mark.slow
@pytest.mark.parametrize("kind", list(campaign.KINDS))
@settings(max_examples=2, deadline=None, print_blob=True, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(100, 10_000))
def test_returned_calibrations_cover_their_true_heading_error(kind: str, seed: int) -> None:
    _check(kind, seed)


def test_the_heading_error_metric_sees_a_wrong_calibration() -> None:
    # The property cannot pass vacuously: the truth scores 0, a calibration off by a tenth of the field in
    # offset scores degrees, and that is what the campaign counts against a stated one-sigma.
    sim, _ = campaign.trial("hemisphere", 0)
    assert campaign.heading_error_deg(sim.truth, sim) < 1e-9
    wrong = magfit.Calibration("wrong", sim.truth.offset + np.array([0.1, 0.0, 0.0]), sim.truth.matrix, 1.0)
    assert campaign.heading_error_deg(wrong, sim) > 3.0
    assert campaign.Outcome("hemisphere", 0, "sphere", "weak", (), error_deg=4.0, stated_deg=1.0).exceeds
    assert not campaign.Outcome("hemisphere", 0, "sphere", "refused", (), error_deg=40.0).exceeds


@pytest.mark.slow
def test_the_campaign_runs_and_writes_its_table(tmp_path: Path) -> None:
    output = tmp_path / "campaign.md"
    status = campaign.main(["--trials", "1", "--kinds", "hemisphere,quantised", "--output", str(output)])
    text = output.read_text(encoding="utf-8")
    assert "| hemisphere |" in text and "| quantised |" in text and "accepted fits exceed" in text
    assert status == 0, text
