"""A file too big for memory is fitted on an even subsample; by default no larger than the method's fit reads
(``MethodSpec.fit_rows``: auto's final fit reads a stride of at most 50 000 samples), and the summary says so.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import magfit
import magfit.pipeline.streaming as streaming
from magfit.cli.app import cli
from magfit.methods.auto import REFIT_ROWS
from magfit.methods.registry import METHODS


@pytest.fixture(scope="module")
def tumble_csv(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, magfit.Simulation]:
    sim = magfit.scenario("mpu9250", "steel").simulate(30_000, seed=4)
    path = tmp_path_factory.mktemp("tumble") / "tumble.csv"
    np.savetxt(path, sim.samples, delimiter=",", header="mx,my,mz", comments="", fmt="%.1f")
    return path, sim


def _calibrate(path: Path, *options: str, tmp_path: Path) -> tuple[str, magfit.Calibration]:
    out = tmp_path / "cal.json"
    run = CliRunner().invoke(cli, ["calibrate", str(path), *options, "-o", str(out)])
    assert run.exit_code == 0, run.output
    return run.stdout, magfit.Calibration.from_json(out.read_text())


def test_auto_declares_the_rows_its_final_fit_reads() -> None:
    assert METHODS["auto"].fit_rows == REFIT_ROWS == 50_000
    assert METHODS["ml"].fit_rows is None  # ml fits every sample it is given


def test_a_streamed_file_is_subsampled_to_the_rows_the_method_reads(
    tumble_csv: tuple[Path, magfit.Simulation], monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    path, sim = tumble_csv
    # Scaled down: memory for 20 000 samples, and auto's final fit reading at most 5 000 of them.
    monkeypatch.setattr(streaming, "memory_sample_limit", lambda: 20_000)
    monkeypatch.setitem(METHODS, "auto", dataclasses.replace(METHODS["auto"], fit_rows=5_000))
    out, calibration = _calibrate(path, tmp_path=tmp_path)
    match = re.search(r"fitted on\s+an even subsample: (\d+) of 30000 samples \((.*)\)", out)
    assert match and 4_000 < int(match.group(1)) <= 5_000, out
    assert "the file has more rows than --max-samples 20000" in match.group(2)
    assert "auto's fit reads at most 5 000" in match.group(2)
    assert calibration.support is not None and calibration.support.verdict == "supported"
    truth = sim.truth
    assert np.linalg.norm(calibration.offset - truth.offset) < 0.01 * truth.field_strength  # the truth
    # The user's --max-samples is taken as given: the method's bound applies only to the default.
    out, _ = _calibrate(path, "--max-samples", "12000", tmp_path=tmp_path)
    match = re.search(r"fitted on\s+an even subsample: (\d+) of 30000 samples \((.*)\)", out)
    assert match and 10_000 < int(match.group(1)) <= 12_000 and "reads at most" not in match.group(2)
