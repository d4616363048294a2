"""The magcal export run by GNU Octave: the ``.m`` file is executed as MATLAB code and ``C = (D - b) * A``
applied to a real recording must give ``Calibration.apply``.

MATLAB's ``magcal`` itself is not in Octave; what the consumer runs is the snippet (``A``, ``b``,
``expmfs``) and the row-vector formula from magcal's documentation. Octave comes from Debian's packages
(``.ci/run`` installs it); without it the test skips, except under CI, where that is a failure.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

import magfit
from magfit.export import export

pytestmark = pytest.mark.external


@pytest.mark.parametrize("root", ["sqrt", "cholesky"])
def test_octave_runs_the_magcal_file(tmp_path: Path, real_data_dir: Path, root: str) -> None:
    octave = shutil.which("octave-cli") or shutil.which("octave")
    if octave is None:
        if os.environ.get("CI") == "true":
            pytest.fail("octave is missing under CI (.ci/run installs Debian's octave)")
        pytest.skip("octave not installed (apt-get install octave)")
    samples = np.loadtxt(real_data_dir / "fxos8700_magneto" / "mag-readings.txt")  # µT
    cal = magfit.fit(samples, method="ellipsoid", root=root).with_unit("uT")
    (tmp_path / "magfit_cal.m").write_text(export(cal, "magcal"))
    np.savetxt(tmp_path / "raw.txt", samples, fmt="%.17g")
    script = (
        "magfit_cal; D = load('raw.txt'); C = (D - b) * A; "
        "fid = fopen('out.txt', 'w'); fprintf(fid, '%.17g %.17g %.17g\\n', C.'); fclose(fid); "
        "fid = fopen('expmfs.txt', 'w'); fprintf(fid, '%.17g\\n', expmfs); fclose(fid);"
    )
    run = subprocess.run(
        [octave, "--no-gui", "--quiet", "--no-init-file", "--eval", script],
        cwd=tmp_path, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    corrected = np.loadtxt(tmp_path / "out.txt")
    np.testing.assert_allclose(corrected, cal.apply(samples), rtol=0, atol=1e-12 * np.max(np.abs(samples)))
    assert float((tmp_path / "expmfs.txt").read_text()) == cal.field_strength
    np.testing.assert_allclose(np.linalg.norm(corrected, axis=1).mean(), cal.field_strength, rtol=0.01)
