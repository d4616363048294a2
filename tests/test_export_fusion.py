"""The Fusion export, compiled against Fusion's own sources and applied by imufusion.

Fusion's C sources come from imufusion's source distributions on PyPI, which ship them
(``Fusion/FusionMath.h``, ``FusionModel.h`` ...). Two releases cover both layouts of ``FusionMatrix``:
1.3.3 (``union { float array[9]; struct {xx ... zz} element; }``, ``FusionModelMagnetic``) and 1.2.11
(``float array[3][3]`` first, ``FusionCalibrationMagnetic``). ``.ci/run`` downloads the two tarballs
into ``build/fusion-sdist`` (``MAGFIT_FUSION_SDIST`` overrides), so the tests need no network;
without them the tests skip, except under CI, where that is a failure. Only the headers are read from
the tarballs, with :mod:`tarfile`, into a temporary folder.

Each program reads real samples, applies Fusion's own model function to the exported
``softIronMatrix`` / ``hardIronOffset`` in float32, and must reproduce ``Calibration.apply``.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import tarfile
import textwrap
from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray

import magfit
from magfit.export import export

SDIST_DIR = Path(os.environ.get("MAGFIT_FUSION_SDIST", Path(__file__).resolve().parents[1] / "build" / "fusion-sdist"))
#: release -> (the FusionMatrix array member it declares, the magnetometer model function)
RELEASES = {
    "1.3.3": ("float array[9];", "FusionModelMagnetic"),
    "1.2.11": ("float array[3][3];", "FusionCalibrationMagnetic"),
}
#: Compiled float32: a few roundings of numbers up to max|raw| (eps 1.2e-7).
RTOL_FLOAT32 = 2e-6
#: gcc as C99 and g++ as C++20 (Fusion's own headers use designated initialisers, C++20 in C++).
LANGUAGES = {"c": ("gcc", "-std=c99"), "c++": ("g++", "-std=c++20")}


def _fusion_headers(release: str, tmp_path: Path) -> Path:
    """Fusion's headers of ``release``, extracted from imufusion's sdist into ``tmp_path/Fusion``."""
    archive = SDIST_DIR / f"imufusion-{release}.tar.gz"
    if not archive.is_file():
        message = (
            f"Fusion's sources not found: {archive} (.ci/run downloads it: "
            f"pip download --no-deps --no-binary imufusion imufusion=={release} -d {SDIST_DIR})"
        )
        if os.environ.get("CI") == "true":
            pytest.fail(message)
        pytest.skip(message)
    target = tmp_path / "Fusion"
    target.mkdir()
    with tarfile.open(archive) as tar:
        for member in tar.getmembers():
            if member.isfile() and re.fullmatch(rf"imufusion-{re.escape(release)}/Fusion/\w+\.h", member.name):
                source = tar.extractfile(member)
                assert source is not None
                (target / Path(member.name).name).write_bytes(source.read())
    assert (target / "Fusion.h").is_file()
    return target


def _compiler(language: str) -> tuple[str, str]:
    name, standard = LANGUAGES[language]
    path = shutil.which(name)
    if path is None:
        if os.environ.get("CI") == "true":
            pytest.fail(f"no {name} under CI")
        pytest.skip(f"no {name}")
    return path, standard


def _fxos(real_data_dir: Path) -> NDArray[np.float64]:
    # NXP FXOS8700, µT, tab-separated x y z, no header.
    return np.loadtxt(real_data_dir / "fxos8700_magneto" / "mag-readings.txt")


def _unc(real_data_dir: Path) -> NDArray[np.float64]:
    # QMC5883L, raw counts, strong hard and soft iron; header mx,my,mz after two preamble lines.
    return np.loadtxt(real_data_dir / "unc_qmc5883l" / "filtered_raw_data.csv", delimiter=",", skiprows=3)


MAIN = """#include <stdio.h>
#include "Fusion.h"
#include "cal.h"
int main(void)
{{
    FusionVector u;
    while (scanf("%f %f %f", &u.array[0], &u.array[1], &u.array[2]) == 3) {{
        const FusionVector c = {model}(u, softIronMatrix, hardIronOffset);
        printf("%.9g %.9g %.9g\\n", c.axis.x, c.axis.y, c.axis.z);
    }}
    return 0;
}}
"""


def _run(
    tmp_path: Path, release: str, language: str, header: str, samples: NDArray[np.float64], flags: tuple[str, ...]
) -> NDArray[np.float64]:
    """Compile MAIN with Fusion's real headers and ``header`` as cal.h, feed it the samples, read the output."""
    headers = _fusion_headers(release, tmp_path)
    layout, model = RELEASES[release]
    assert layout in (headers / "FusionMath.h").read_text()  # the layout this release is meant to cover
    compiler, standard = _compiler(language)
    (tmp_path / "cal.h").write_text(header)
    (tmp_path / "main.c").write_text(MAIN.format(model=model))
    exe = tmp_path / "main"
    build = subprocess.run(
        [compiler, "-x", language, standard, *flags, "-I", str(headers), "-I", str(tmp_path), str(tmp_path / "main.c"),
         "-o", str(exe), "-lm"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert build.returncode == 0, build.stderr
    stdin = "\n".join(" ".join(f"{v:.9g}" for v in row) for row in samples)
    result = subprocess.run([str(exe)], input=stdin, capture_output=True, text=True, check=True, timeout=60)
    return np.loadtxt(result.stdout.splitlines())


def _close(actual: NDArray[np.float64], expected: NDArray[np.float64], raw: NDArray[np.float64]) -> None:
    np.testing.assert_allclose(actual, expected, rtol=0, atol=RTOL_FLOAT32 * float(np.max(np.abs(raw))))


@pytest.fixture(scope="module", params=["fxos8700_uT_cholesky", "unc_qmc5883l_counts"])
def fitted(request: pytest.FixtureRequest, real_data_dir: Path) -> tuple[magfit.Calibration, NDArray[np.float64]]:
    """A non-symmetric (Cholesky) µT fit and a strong-soft-iron fit in raw counts, with their samples.

    A non-symmetric matrix catches a transposed export; the counts file has a semi-axis ratio of about
    2.2, so a matrix read column-first is far off.
    """
    if request.param == "fxos8700_uT_cholesky":
        samples = _fxos(real_data_dir)
        return magfit.fit(samples, method="ellipsoid", root="cholesky").with_unit("uT"), samples
    samples = _unc(real_data_dir)[3000:]  # after the 60 s warm-up
    return magfit.fit(samples, method="ellipsoid").with_unit("counts"), samples


@pytest.mark.parametrize("language", ["c", "c++"])
@pytest.mark.external
def test_current_fusion_applies_the_export_as_magfit_does(
    tmp_path: Path, fitted: tuple[magfit.Calibration, NDArray[np.float64]], language: str
) -> None:
    # Fusion 1.3: flat float array[9]; no warning at all, pedantic.
    cal, samples = fitted
    out = _run(
        tmp_path, "1.3.3", language, export(cal, "fusion"), samples, ("-Wall", "-Wextra", "-pedantic", "-Werror")
    )
    _close(out, cal.apply(samples), samples)


@pytest.mark.parametrize("language", ["c", "c++"])
@pytest.mark.external
def test_fusion_before_1_3_applies_the_export_as_magfit_does(
    tmp_path: Path, fitted: tuple[magfit.Calibration, NDArray[np.float64]], language: str
) -> None:
    # Fusion 1.2: nested float array[3][3], filled by brace elision. C's -Wall warns about the elided
    # row braces (-Wmissing-braces, harmless: the values are right); every other warning is an error.
    cal, samples = fitted
    flags = ("-Wall", "-Wextra", "-Werror", "-Wno-missing-braces")
    out = _run(tmp_path, "1.2.11", language, export(cal, "fusion"), samples, flags)
    _close(out, cal.apply(samples), samples)


@pytest.mark.external
def test_nested_row_braces_are_wrong_for_current_fusion(tmp_path: Path, real_data_dir: Path) -> None:
    # The form magfit wrote before issue 12, {{{a, b, c}, {d, e, f}, {g, h, i}}}: with Fusion 1.3 it fills
    # the first column only in C and does not compile in C++. The tests above would catch it.
    samples = _fxos(real_data_dir)
    cal = magfit.fit(samples, method="ellipsoid", root="cholesky").with_unit("uT")
    rows = ", ".join("{" + ", ".join(f"{v:.9e}f" for v in row) + "}" for row in cal.matrix)
    offset = ", ".join(f"{v:.9e}f" for v in cal.offset)
    nested = (
        f"static const FusionMatrix softIronMatrix = {{{{{rows}}}}};\n"
        f"static const FusionVector hardIronOffset = {{{{{offset}}}}};\n"
    )
    out = _run(tmp_path, "1.3.3", "c", nested, samples, ("-w",))
    first_column = np.zeros((3, 3))
    first_column.flat[:3] = cal.matrix[:, 0]  # a, d, g land in xx, xy, xz
    _close(out, (samples - cal.offset) @ first_column.T, samples)
    assert not np.allclose(out, cal.apply(samples), atol=1.0)
    (tmp_path / "cpp").mkdir()
    with pytest.raises(AssertionError, match="error"):
        _run(tmp_path / "cpp", "1.3.3", "c++", nested, samples, ())


def test_imufusion_model_magnetic_applies_the_python_block(
    fitted: tuple[magfit.Calibration, NDArray[np.float64]],
) -> None:
    # imufusion (the Python package, Fusion's C inside) applies the arrays the header's Python block assigns.
    imufusion = pytest.importorskip("imufusion") if os.environ.get("CI") != "true" else __import__("imufusion")
    cal, samples = fitted
    text = export(cal, "fusion")
    block = text.split("Python (imufusion) >>>")[1].split("<<< Python")[0]
    names: dict[str, NDArray[np.float64]] = {}
    exec(textwrap.dedent("\n".join(line.removeprefix(" *") for line in block.splitlines())), names)
    corrected = np.array(
        [imufusion.model_magnetic(u, names["soft_iron_matrix"], names["hard_iron_offset"]) for u in samples]
    )
    _close(corrected, cal.apply(samples), samples)


def test_fusion_header_warns_about_a_cholesky_root(real_data_dir: Path) -> None:
    samples = _fxos(real_data_dir)
    chol = magfit.fit(samples, method="ellipsoid", root="cholesky").with_unit("uT")
    sym = magfit.fit(samples, method="ellipsoid").with_unit("uT")
    text = export(chol, "fusion")
    angle = float(re.search(r"turns the corrected field by ([\d.]+) deg", text).group(1))  # type: ignore[union-attr]
    q = chol.matrix @ np.linalg.inv(sym.matrix)  # the rotation between the two roots
    assert angle == pytest.approx(np.degrees(np.arccos((np.trace(q) - 1) / 2)), abs=0.01)
    assert "refit with root='sqrt'" in text
    assert "WARNING" not in export(sym, "fusion")
