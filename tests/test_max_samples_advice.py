"""--max-samples below the cells of directions a file fills is refused with a least budget that works when given.

The streamed subsample bins a pool of every k-th row (k from the budget), which fills fewer cells than the
whole file; the advice counts the cells of every row, so that following it is accepted whatever pool it
then bins. Ground truth: the samples lie on a known sphere, and the accepted fit finds its centre.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from magfit.cli import cli

CENTRE = np.array([10.0, -5.0, 3.0])


def sphere_csv(path: Path, n: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n, 3))
    v = v / np.linalg.norm(v, axis=1)[:, None] * 50.0 + CENTRE + rng.normal(0.0, 0.2, (n, 3))
    np.savetxt(path, v, fmt="%.6f", delimiter=",", header="mx,my,mz", comments="")


@pytest.mark.parametrize(("n", "seed", "budget"), [(300, 1, 10), (300, 2, 150), (2000, 3, 40), (2000, 4, 300)])
def test_the_advised_budget_is_accepted(tmp_path: Path, n: int, seed: int, budget: int) -> None:
    path = tmp_path / "mag.csv"
    sphere_csv(path, n, seed)
    first = CliRunner().invoke(cli, ["calibrate", str(path), "--max-samples", str(budget)])
    assert first.exit_code == 2, first.output
    advised = re.search(r"give at least --max-samples (\d+)", first.stderr)
    assert advised, first.stderr
    least = int(advised.group(1))
    assert budget < least <= n
    output = tmp_path / "cal.json"
    second = CliRunner().invoke(cli, ["calibrate", str(path), "--max-samples", str(least), "-o", str(output)])
    assert second.exit_code == 0, second.stderr
    offset = np.array(json.loads(output.read_text())["offset"])
    assert np.linalg.norm(offset - CENTRE) < 1.0
