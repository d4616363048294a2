"""Firmware exports: each file, parsed back and applied with the target's own formula, gives magfit's field.

Every target is checked the same way: export a calibration fitted on a real recording, parse the text
as the target would, apply the target's documented correction (re-implemented here from the target's
source, independently of magfit/export), and compare with ``Calibration.apply`` after the target's
unit conversion. Tolerances: the parameter files keep 9 significant digits (``%.9g``, float32
precision), a relative rounding of at most 5e-9 per number; with |matrix| ~ 1 the corrected field is
then off by at most ~1e-8 x (|raw| + |offset|), so ``RTOL_TEXT = 1e-7`` of the largest raw magnitude
bounds it with margin. Compiled C runs in float32 (eps 1.2e-7, a few roundings per component):
``RTOL_FLOAT32 = 2e-6`` of the largest raw magnitude.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import textwrap
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray

import magfit
from magfit.errors import ExportError, MagfitError, OptionError
from magfit.export import FORMATS, export

RTOL_TEXT = 1e-7
RTOL_FLOAT32 = 2e-6
NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"


# ---------------------------------------------------------------------- real recordings


def _fxos(real_data_dir: Path) -> NDArray[np.float64]:
    # NXP FXOS8700, µT, tab-separated x y z, no header (README of the recordings).
    return np.loadtxt(real_data_dir / "fxos8700_magneto" / "mag-readings.txt")


def _hamagure(real_data_dir: Path) -> NDArray[np.float64]:
    # Unknown sensor, gauss, header x,y,z (CRLF line ends).
    return np.loadtxt(real_data_dir / "hamagure_gauss" / "data-set_1.csv", delimiter=",", skiprows=1)


@pytest.fixture(scope="module", params=["fxos8700_uT", "hamagure_gauss"])
def recording(request: pytest.FixtureRequest, real_data_dir: Path) -> tuple[NDArray[np.float64], str]:
    """(samples, unit) of a real recording."""
    if request.param == "fxos8700_uT":
        return _fxos(real_data_dir), "uT"
    return _hamagure(real_data_dir), "G"


@pytest.fixture(scope="module")
def fitted(recording: tuple[NDArray[np.float64], str]) -> tuple[magfit.Calibration, NDArray[np.float64]]:
    """An ellipsoid fit (symmetric root) of the recording, labelled with its unit, and its samples."""
    samples, unit = recording
    return magfit.fit(samples, method="ellipsoid").with_unit(unit), samples


@pytest.fixture(scope="module", params=["sqrt", "cholesky"])
def fitted_any_root(
    request: pytest.FixtureRequest, recording: tuple[NDArray[np.float64], str]
) -> tuple[magfit.Calibration, NDArray[np.float64]]:
    """As ``fitted``, also with the upper-triangular Cholesky root: a non-symmetric matrix, so that a
    transposed or row/column-swapped export cannot pass."""
    samples, unit = recording
    return magfit.fit(samples, method="ellipsoid", root=request.param).with_unit(unit), samples


def _close(actual: NDArray[np.float64], expected: NDArray[np.float64], raw: NDArray[np.float64], rtol: float) -> None:
    np.testing.assert_allclose(actual, expected, rtol=0, atol=rtol * float(np.max(np.abs(raw))))


# ---------------------------------------------------------------------- parsers and target formulas


def parse_ardupilot(text: str) -> dict[str, float]:
    """Mission Planner / MAVProxy .param: ``NAME,VALUE`` lines, ``#`` comments."""
    params = {}
    for line in text.splitlines():
        if line.strip() and not line.startswith("#"):
            name, value = line.split(",")
            params[name] = float(value)
    return params


def ardupilot_correct(p: dict[str, float], raw_mg: NDArray[np.float64]) -> NDArray[np.float64]:
    """AP_Compass_Backend::correct_field, row by row: mag += ofs; mag *= scale; mag = mat * mag."""
    out = np.empty_like(raw_mg)
    ofs = np.array([p["COMPASS_OFS_X"], p["COMPASS_OFS_Y"], p["COMPASS_OFS_Z"]])
    mat = np.array(
        [
            [p["COMPASS_DIA_X"], p["COMPASS_ODI_X"], p["COMPASS_ODI_Y"]],
            [p["COMPASS_ODI_X"], p["COMPASS_DIA_Y"], p["COMPASS_ODI_Z"]],
            [p["COMPASS_ODI_Y"], p["COMPASS_ODI_Z"], p["COMPASS_DIA_Z"]],
        ]
    )
    scale = p["COMPASS_SCALE"]
    for i, sample in enumerate(raw_mg):
        mag = sample + ofs
        if 0.85 <= scale <= 1.4:  # Compass::have_scale_factor (COMPASS_MIN/MAX_SCALE_FACTOR)
            mag = mag * scale
        out[i] = mat @ mag
    return out


def parse_px4(text: str) -> dict[str, float]:
    """QGroundControl parameter file: ``vehicle<TAB>component<TAB>name<TAB>value<TAB>type`` lines."""
    params = {}
    for line in text.splitlines():
        if line.strip() and not line.startswith("#"):
            vehicle, component, name, value, kind = line.split("\t")
            assert (vehicle, component, kind) == ("1", "1", "9")  # vehicle 1, autopilot, MAV_PARAM_TYPE_REAL32
            params[name] = float(value)
    return params


def px4_correct(p: dict[str, float], raw_g: NDArray[np.float64]) -> NDArray[np.float64]:
    """calibration::Magnetometer::Correct without the rotation: S * (raw - offset)."""
    off = np.array([p["CAL_MAG0_XOFF"], p["CAL_MAG0_YOFF"], p["CAL_MAG0_ZOFF"]])
    s = np.array(
        [
            [p["CAL_MAG0_XSCALE"], p["CAL_MAG0_XODIAG"], p["CAL_MAG0_YODIAG"]],
            [p["CAL_MAG0_XODIAG"], p["CAL_MAG0_YSCALE"], p["CAL_MAG0_ZODIAG"]],
            [p["CAL_MAG0_YODIAG"], p["CAL_MAG0_ZODIAG"], p["CAL_MAG0_ZSCALE"]],
        ]
    )
    return np.array([s @ (sample - off) for sample in raw_g])


def c_array(text: str, name: str) -> NDArray[np.float64]:
    """The numbers of the C initialiser of ``name`` (float literals with an ``f`` suffix)."""
    match = re.search(rf"{name}(?:\[3\])+ = \{{(.*?)\}};", text, re.S)
    assert match, f"{name} not found"
    return np.array([float(v) for v in re.findall(rf"({NUMBER})f", match.group(1))])


def parse_fusion_c(text: str) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    matrix = re.search(r"FusionMatrix softIronMatrix = \{(.*?)\};", text, re.S)
    offset = re.search(r"FusionVector hardIronOffset = \{(.*?)\};", text, re.S)
    assert matrix and offset
    m = np.array([float(v) for v in re.findall(rf"({NUMBER})f", matrix.group(1))]).reshape(3, 3)  # row-major
    h = np.array([float(v) for v in re.findall(rf"({NUMBER})f", offset.group(1))])
    return m, h


def parse_fusion_python(text: str) -> dict[str, NDArray[np.float64]]:
    """Execute the Python block of the Fusion export, as a user would paste it."""
    block = text.split("Python (imufusion) >>>")[1].split("<<< Python")[0]
    code = textwrap.dedent("\n".join(line.removeprefix(" *") for line in block.splitlines()))
    names: dict[str, NDArray[np.float64]] = {}
    exec(code, names)
    return names


def parse_magcal(text: str) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    a = re.search(r"^A = \[(.*?)\];", text, re.S | re.M)
    b = re.search(r"^b = \[(.*?)\];", text, re.M)
    expmfs = re.search(rf"^expmfs = ({NUMBER});", text, re.M)
    assert a and b and expmfs
    rows = [[float(v) for v in row.split(",")] for row in a.group(1).split(";")]
    return np.array(rows), np.array([float(v) for v in b.group(1).split(",")]), float(expmfs.group(1))


# ---------------------------------------------------------------------- each target reproduces apply()


def test_json_is_lossless_and_records_the_unit(fitted_any_root: tuple[magfit.Calibration, NDArray[np.float64]]) -> None:
    cal, samples = fitted_any_root
    text = export(cal.with_unit(None), "json", unit="µT")
    back = magfit.Calibration.from_json(text)
    assert back == cal.with_unit("uT")  # the unit passed is recorded, canonically
    data = json.loads(text)
    assert data["convention"] == "corrected = matrix @ (raw - offset)"
    assert data["schema_version"] == 2 and data["n_samples"] == len(samples)
    assert data["details"]["root"] in ("sqrt", "cholesky")  # the fit's details travel with it
    np.testing.assert_array_equal(back.apply(samples), cal.apply(samples))
    assert magfit.Calibration.from_json(export(cal, "json")) == cal  # no unit given: the recorded one stays


def test_c_header_arrays_reproduce_apply(fitted_any_root: tuple[magfit.Calibration, NDArray[np.float64]]) -> None:
    cal, samples = fitted_any_root
    text = export(cal, "c")
    offset = c_array(text, "magfit_offset")
    matrix = c_array(text, "magfit_matrix").reshape(3, 3)  # [i][j] = row i, column j
    strength = float(re.search(rf"magfit_field_strength = ({NUMBER})f;", text).group(1))  # type: ignore[union-attr]
    corrected = np.array([matrix @ (sample - offset) for sample in samples])
    _close(corrected, cal.apply(samples), samples, RTOL_TEXT)
    assert strength == pytest.approx(cal.field_strength, rel=1e-8)
    assert "corrected = matrix * (raw - offset)" in text
    assert f"corrected: {cal.unit}" in text
    assert text.count("#ifndef MAGFIT_CALIBRATION_H") == 1 and "#endif /* MAGFIT_CALIBRATION_H */" in text


def test_ardupilot_correct_field_reproduces_apply_in_milligauss(
    fitted: tuple[magfit.Calibration, NDArray[np.float64]],
) -> None:
    cal, samples = fitted
    k = {"uT": 10.0, "G": 1000.0}[cal.unit]  # mG per input unit
    params = parse_ardupilot(export(cal, "ardupilot"))
    assert list(params) == [
        *(f"COMPASS_OFS_{a}" for a in "XYZ"),
        *(f"COMPASS_DIA_{a}" for a in "XYZ"),
        *(f"COMPASS_ODI_{a}" for a in "XYZ"),
        "COMPASS_SCALE",
    ]
    corrected = ardupilot_correct(params, k * samples)
    _close(corrected, k * cal.apply(samples), k * samples, RTOL_TEXT)
    # ArduPilot adds its offsets: they are the negative of magfit's, in mG.
    np.testing.assert_allclose([params[f"COMPASS_OFS_{a}"] for a in "XYZ"], -k * cal.offset, rtol=1e-8)
    # The header names the firmware function whose formula the file follows (a rename once garbled it).
    assert "(AP_Compass_Backend::correct_field)" in export(cal, "ardupilot")


def test_px4_correct_reproduces_apply_in_gauss(fitted: tuple[magfit.Calibration, NDArray[np.float64]]) -> None:
    cal, samples = fitted
    k = {"uT": 0.01, "G": 1.0}[cal.unit]  # gauss per input unit
    text = export(cal, "px4")
    params = parse_px4(text)
    assert len(params) == 9
    _close(px4_correct(params, k * samples), k * cal.apply(samples), k * samples, RTOL_TEXT)
    assert text.startswith("# Onboard parameters for Vehicle 1\n")
    assert "# Vehicle-Id\tComponent-Id\tName\tValue\tType" in text


def test_fusion_c_and_python_reproduce_apply(fitted_any_root: tuple[magfit.Calibration, NDArray[np.float64]]) -> None:
    cal, samples = fitted_any_root
    text = export(cal, "fusion")
    m, h = parse_fusion_c(text)
    # FusionModelMagnetic: calibrated = softIronMatrix * (uncalibrated - hardIronOffset)
    _close(np.array([m @ (u - h) for u in samples]), cal.apply(samples), samples, RTOL_TEXT)
    names = parse_fusion_python(text)
    s, o = names["soft_iron_matrix"], names["hard_iron_offset"]
    assert s.shape == (3, 3) and o.shape == (3,)
    _close(np.array([s @ (u - o) for u in samples]), cal.apply(samples), samples, RTOL_TEXT)
    # The offset given for Fusion releases before the model change: calibrated = S * uncalibrated - h.
    legacy = re.search(r"need instead\n \*     hardIronOffset = \{(.*)\}", text)
    assert legacy
    h_old = np.array([float(v) for v in re.findall(rf"({NUMBER})f", legacy.group(1))])
    _close(np.array([m @ u - h_old for u in samples]), cal.apply(samples), samples, RTOL_TEXT)


def test_magcal_row_form_reproduces_apply(fitted_any_root: tuple[magfit.Calibration, NDArray[np.float64]]) -> None:
    cal, samples = fitted_any_root
    a, b, expmfs = parse_magcal(export(cal, "magcal"))
    corrected = (samples - b) @ a  # MATLAB: C = (D - b) * A, one sample per row
    # 17 significant digits: exact to double rounding.
    np.testing.assert_allclose(corrected, cal.apply(samples), rtol=0, atol=1e-12 * np.max(np.abs(samples)))
    assert expmfs == cal.field_strength
    np.testing.assert_array_equal(b, cal.offset)


# ---------------------------------------------------------------------- compiled C


COMPILERS = {"c": (("cc", "gcc", "clang"), "-std=c99"), "c++": (("c++", "g++", "clang++"), "-std=c++11")}


def _compile_and_run(
    tmp_path: Path, language: str, files: dict[str, str], main: str, samples: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Compile ``main`` with the headers ``files`` (warnings are errors), feed it ``samples``, read its output."""
    names, standard = COMPILERS[language]
    compiler = next((path for path in map(shutil.which, names) if path), None)
    if compiler is None:
        pytest.skip(f"no {language} compiler")
    for name, content in files.items():
        (tmp_path / name).write_text(content)
    (tmp_path / "main.c").write_text(main)
    exe = tmp_path / "main"
    subprocess.run(
        [
            compiler,
            "-x",
            language,
            standard,
            "-pedantic",
            "-Wall",
            "-Wextra",
            "-Werror",
            "-I",
            str(tmp_path),
            str(tmp_path / "main.c"),
            "-o",
            str(exe),
        ],
        check=True,
        capture_output=True,
        timeout=60,
    )
    stdin = "\n".join(" ".join(f"{v:.9g}" for v in row) for row in samples)
    result = subprocess.run([str(exe)], input=stdin, capture_output=True, text=True, check=True, timeout=60)
    return np.loadtxt(result.stdout.splitlines())


@pytest.mark.parametrize("language", ["c", "c++"])
def test_c_header_compiles_and_corrects(tmp_path: Path, real_data_dir: Path, language: str) -> None:
    samples = _fxos(real_data_dir)
    cal = magfit.fit(samples, method="ellipsoid", root="cholesky").with_unit("uT")  # non-symmetric matrix
    main = """#include <stdio.h>
#include "cal.h"
int main(void)
{
    float raw[3], out[3];
    while (scanf("%f %f %f", &raw[0], &raw[1], &raw[2]) == 3) {
        magfit_correct(raw, out);
        printf("%.9g %.9g %.9g %.9g\\n", out[0], out[1], out[2], magfit_field_strength);
    }
    return 0;
}
"""
    out = _compile_and_run(tmp_path, language, {"cal.h": export(cal, "c")}, main, samples)
    _close(out[:, :3], cal.apply(samples), samples, RTOL_FLOAT32)
    assert out[0, 3] == pytest.approx(cal.field_strength, rel=1e-7)


# The Fusion header is compiled against Fusion's real sources in tests/test_export_fusion.py.


# ---------------------------------------------------------------------- ground truth and special cases


def test_ardupilot_and_px4_recover_the_simulated_field() -> None:
    # Eq. (1) with a known symmetric W and V in µT: the exported correction must give back the true
    # field B R e, which has length B = 50 µT = 500 mG = 0.5 G, to float precision (no noise).
    w = np.array([[1.1, 0.05, -0.02], [0.05, 0.95, 0.03], [-0.02, 0.03, 1.0]])
    sim = magfit.simulate(500, soft_iron=w, hard_iron=[25.0, -40.0, 12.0], field_strength=50.0, seed=3)
    truth = magfit.Calibration("truth", sim.truth.offset, sim.truth.matrix, 50.0, unit="uT")
    field = (sim.clean - sim.hard_iron) @ np.linalg.inv(w).T  # B R e of eq. (1), µT
    ap = ardupilot_correct(parse_ardupilot(export(truth, "ardupilot")), 10.0 * sim.clean)
    _close(ap, 10.0 * field, 10.0 * sim.clean, RTOL_TEXT)
    np.testing.assert_allclose(np.linalg.norm(ap, axis=1), 500.0, rtol=1e-6)
    px = px4_correct(parse_px4(export(truth, "px4")), 0.01 * sim.clean)
    np.testing.assert_allclose(np.linalg.norm(px, axis=1), 0.5, rtol=1e-6)


def _random_calibration(seed: int, symmetric: bool) -> tuple[magfit.Calibration, NDArray[np.float64]]:
    """A calibration inside ArduPilot's and PX4's limits (µT), and raw samples around its ellipsoid."""
    rng = np.random.default_rng(seed)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    spd = q @ np.diag(rng.uniform(0.7, 1.4, 3)) @ q.T  # symmetric positive definite
    matrix = spd if symmetric else spd @ np.linalg.qr(rng.normal(size=(3, 3)))[0]
    matrix = matrix * np.sign(np.linalg.det(matrix)) / abs(np.linalg.det(matrix)) ** (1 / 3)  # det = +1
    cal = magfit.Calibration("test", rng.uniform(-100, 100, 3), matrix, rng.uniform(30, 60), unit="uT")
    directions = rng.normal(size=(50, 3))
    field = cal.field_strength * directions / np.linalg.norm(directions, axis=1, keepdims=True)
    return cal, field @ np.linalg.inv(matrix).T + cal.offset  # raw = matrix⁻¹ field + offset


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_random_symmetric_calibrations_survive_ardupilot_and_px4(seed: int) -> None:
    cal, raw = _random_calibration(seed, symmetric=True)
    _close(
        ardupilot_correct(parse_ardupilot(export(cal, "ardupilot")), 10 * raw), 10 * cal.apply(raw), 10 * raw, RTOL_TEXT
    )
    _close(px4_correct(parse_px4(export(cal, "px4")), 0.01 * raw), 0.01 * cal.apply(raw), 0.01 * raw, RTOL_TEXT)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_random_full_matrices_survive_c_fusion_and_magcal(seed: int) -> None:
    cal, raw = _random_calibration(seed, symmetric=False)
    expected = cal.apply(raw)
    text = export(cal, "c")
    offset, matrix = c_array(text, "magfit_offset"), c_array(text, "magfit_matrix").reshape(3, 3)
    _close((raw - offset) @ matrix.T, expected, raw, RTOL_TEXT)
    m, h = parse_fusion_c(export(cal, "fusion"))
    _close((raw - h) @ m.T, expected, raw, RTOL_TEXT)
    a, b, _ = parse_magcal(export(cal, "magcal"))
    _close((raw - b) @ a, expected, raw, 1e-12)


def test_cholesky_root_is_exported_as_the_symmetric_root(real_data_dir: Path) -> None:
    samples = _fxos(real_data_dir)
    chol = magfit.fit(samples, method="ellipsoid", root="cholesky").with_unit("uT")
    sym = magfit.fit(samples, method="ellipsoid", root="sqrt").with_unit("uT")
    for target, k, correct, parse in (
        ("ardupilot", 10.0, ardupilot_correct, parse_ardupilot),
        ("px4", 0.01, px4_correct, parse_px4),
    ):
        text = export(chol, target)
        assert "Cholesky root" in text and "rotated by" in text
        corrected = correct(parse(text), k * samples)  # type: ignore[operator]
        # Same |corrected| as magfit's apply() of the Cholesky calibration (same ellipsoid) ...
        np.testing.assert_allclose(
            np.linalg.norm(corrected, axis=1), k * np.linalg.norm(chol.apply(samples), axis=1), rtol=1e-7
        )
        # ... and exactly the symmetric-root calibration's vectors.
        _close(corrected, k * sym.apply(samples), k * samples, RTOL_TEXT)
    angle = float(re.search(r"rotated by ([\d.]+) deg", export(chol, "ardupilot")).group(1))  # type: ignore[union-attr]
    q = chol.matrix @ np.linalg.inv(sym.matrix)  # the rotation between the two roots
    assert angle == pytest.approx(np.degrees(np.arccos((np.trace(q) - 1) / 2)), abs=2e-3)


def test_identity_changes_nothing_in_every_format() -> None:
    # An identity calibration must export to a correction that returns raw unchanged (0.5 G field).
    cal = magfit.Calibration.identity(field_strength=0.5, unit="G")
    raw = np.array([[0.3, -0.2, 0.35], [-0.1, 0.4, -0.25]])
    np.testing.assert_array_equal(c_array(export(cal, "c"), "magfit_matrix").reshape(3, 3), np.eye(3))
    np.testing.assert_allclose(ardupilot_correct(parse_ardupilot(export(cal, "ardupilot")), 1000 * raw), 1000 * raw)
    np.testing.assert_allclose(px4_correct(parse_px4(export(cal, "px4")), raw), raw)
    a, b, _ = parse_magcal(export(cal, "magcal"))
    np.testing.assert_array_equal((raw - b) @ a, raw)


@pytest.mark.parametrize("name", list(FORMATS))
def test_every_format_is_reproducible_and_date_free(name: str) -> None:
    unit = "counts" if FORMATS[name].unit == "counts" else "uT"  # INAV and Betaflight store raw counts
    cal = magfit.Calibration("ellipsoid", [1.0, -2.0, 3.0], np.diag([1.1, 1.0, 1 / 1.1]), 45.0, unit=unit, n_samples=9)
    spec = FORMATS[name]
    assert spec.name == name and spec.extension.startswith(".") and "\n" not in spec.summary and spec.summary
    first, second = export(cal, name), export(cal, name)
    assert first == second and first.endswith("\n")
    assert not re.search(r"\d{4}-\d{2}-\d{2}|\d{2}:\d{2}:\d{2}", first)


@pytest.mark.parametrize("name", ["json", "c", "fusion", "magcal"])
def test_formats_without_conversion_accept_counts(name: str) -> None:
    cal = magfit.Calibration("ellipsoid", [100.0, -20.0, 5.0], np.eye(3), 400.0, unit="counts")
    assert "counts" in export(cal, name)
    assert export(cal.with_unit(None), name)  # no unit at all is fine too


def test_unit_override_is_written_canonically() -> None:
    cal = magfit.Calibration("ellipsoid", [1.0, 2.0, 3.0], np.eye(3), 50.0, unit="counts")
    assert "corrected: uT" in export(cal, "c", unit="microtesla")
    assert "b, C and expmfs: nT" in export(cal, "magcal", unit="nanotesla")
    # The override converts too: 50 "uT" is 500 mG, accepted where counts are refused.
    assert "COMPASS_OFS_X,-10\n" in export(cal, "ardupilot", unit="µT")


# ---------------------------------------------------------------------- refusals


def _cal(offset=(0.0, 0.0, 0.0), matrix=None, strength: float = 50.0, unit: str | None = "uT", **details: str):
    return magfit.Calibration(
        "test", np.asarray(offset, float), np.eye(3) if matrix is None else matrix, strength, unit=unit, details=details
    )


def test_unknown_format_lists_the_valid_ones() -> None:
    with pytest.raises(
        OptionError, match=r"unknown export format 'mavlink'; valid formats: json \(\.json\), c \(\.h\)"
    ):
        export(_cal(), "mavlink")
    with pytest.raises(OptionError, match="ardupilot"):
        export(_cal(), "ArduPilot")


def test_not_a_calibration_is_refused() -> None:
    with pytest.raises(MagfitError, match="takes a magfit.Calibration, got dict"):
        export({"offset": [0, 0, 0]}, "json")  # type: ignore[arg-type]


@pytest.mark.parametrize("target", ["ardupilot", "px4"])
def test_converting_targets_need_a_physical_unit(target: str) -> None:
    with pytest.raises(ExportError, match="does not record the unit of its samples; pass unit="):
        export(_cal(unit=None), target)
    with pytest.raises(ExportError, match="raw counts of unknown scale"):
        export(_cal(unit="counts"), target)
    with pytest.raises(ExportError, match="raw counts of unknown scale"):
        export(_cal(), target, unit="LSB")
    with pytest.raises(ExportError, match="unit 'furlongs' is not one magfit knows"):
        export(_cal(unit="furlongs"), target)
    with pytest.raises(OptionError, match="unknown unit 'furlong'"):
        export(_cal(), target, unit="furlong")


@pytest.mark.parametrize("target", ["ardupilot", "px4"])
def test_non_symmetric_matrix_is_refused_unless_a_cholesky_root(target: str) -> None:
    turn = np.array([[np.cos(0.3), -np.sin(0.3), 0.0], [np.sin(0.3), np.cos(0.3), 0.0], [0.0, 0.0, 1.0]])
    with pytest.raises(ExportError, match="not symmetric .* may encode an axis rotation"):
        export(_cal(matrix=turn), target)
    export(_cal(matrix=turn, root="cholesky"), target)  # an artefact of the factor: converted, with a note


def test_ardupilot_offset_limit() -> None:
    # COMPASS_OFFS_MAX = 1800 mG on the offset length: 180 µT passes, 180.1 µT does not.
    export(_cal(offset=(180.0, 0.0, 0.0)), "ardupilot")
    with pytest.raises(ExportError, match=r"offset is 1801 mG long, above COMPASS_OFFS_MAX \(1800 mG"):
        export(_cal(offset=(180.1, 0.0, 0.0)), "ardupilot")
    with pytest.raises(ExportError, match="COMPASS_OFFS_MAX"):
        export(_cal(offset=(110.0, 110.0, 110.0)), "ardupilot")  # 1905 mG long, each axis below 1800


@pytest.mark.parametrize(("strength", "unit"), [(18.4, "uT"), (87.6, "uT"), (0.1, "G"), (52.9, "G")])
def test_ardupilot_field_strength_limit(strength: float, unit: str) -> None:
    # AP_Arming 'Check mag field' accepts 185-875 mG; 52.9 "G" is the usual µT-labelled-as-gauss mistake.
    with pytest.raises(
        ExportError, match=rf"Check mag field.*check the unit of the samples \(unit='{unit}' was used\)"
    ):
        export(_cal(offset=(28.6, -40.0, -27.4), strength=strength, unit=unit), "ardupilot")


def test_ardupilot_field_strength_bounds_are_inclusive() -> None:
    export(_cal(strength=18.5), "ardupilot")
    export(_cal(strength=87.5), "ardupilot")


def test_ardupilot_diagonal_and_offdiagonal_limits() -> None:
    with pytest.raises(ExportError, match=r"COMPASS_DIA only in \(0.2, 5.0\)"):
        export(_cal(matrix=np.diag([6.0, 0.5, 1 / 3])), "ardupilot")
    with pytest.raises(ExportError, match=r"COMPASS_DIA only in \(0.2, 5.0\)"):
        export(_cal(matrix=np.diag([0.2, 2.5, 2.0])), "ardupilot")
    with pytest.raises(ExportError, match=r"\|COMPASS_ODI\| < 1.0"):
        export(_cal(matrix=np.array([[1.5, 1.0, 0.0], [1.0, 1.5, 0.0], [0.0, 0.0, 1.0]])), "ardupilot")
    export(_cal(matrix=np.array([[1.5, 0.99, 0.0], [0.99, 1.5, 0.0], [0.0, 0.0, 1.0]])), "ardupilot")


@pytest.mark.parametrize(("strength", "unit"), [(19.9, "uT"), (70.0, "uT"), (0.75, "G"), (50.0, "G")])
def test_px4_field_strength_limit(strength: float, unit: str) -> None:
    # mag_calibration.cpp check_calibration_result: sphere radius in [0.2, 0.7) G.
    with pytest.raises(ExportError, match=r"sphere radius is outside \[0.2, 0.7\) G"):
        export(_cal(strength=strength, unit=unit), "px4")
    export(_cal(strength=20.0), "px4")
    export(_cal(strength=69.99), "px4")


def test_px4_refuses_non_positive_scales() -> None:
    with pytest.raises(ExportError, match="non-positive CAL_MAG0_\\*SCALE"):
        export(_cal(matrix=np.diag([-1.0, -1.0, 1.0])), "px4")


def test_px4_large_offset_is_written_with_a_warning() -> None:
    # PX4 only warns above 1.3 G per axis (the sensor may saturate); the file says so.
    text = export(_cal(offset=(0.0, 150.0, 0.0)), "px4")
    assert "# WARNING: an offset exceeds 1.3 G" in text
    assert parse_px4(text)["CAL_MAG0_YOFF"] == 1.5
    assert "WARNING" not in export(_cal(offset=(0.0, 130.0, 0.0)), "px4")


def test_docs_examples_run() -> None:
    # The Python examples of docs/exports.md must keep working (they assert their own results).
    doc = Path(__file__).resolve().parents[1] / "docs" / "exports.md"
    blocks = re.findall(r"```python\n(.*?)```", doc.read_text(encoding="utf-8"), re.S)
    assert len(blocks) == 7
    for block in blocks:
        exec(compile(block, str(doc), "exec"), {})


@pytest.mark.parametrize("name", [n for n in FORMATS if n not in ("json", "adafruit-json")])
def test_odd_method_names_cannot_break_out_of_comments(name: str) -> None:
    unit = "counts" if FORMATS[name].unit == "counts" else "uT"
    cal = magfit.Calibration("evil */\n#define X 1\nset x = 1", np.zeros(3), np.eye(3), 50.0, unit=unit)
    text = export(cal, name)
    lines = text.splitlines()
    assert not any(line.startswith(("#define X", "set x")) for line in lines)  # stays inside one comment line
    if name in ("c", "fusion", "adafruit"):
        assert text.index("*/") > text.index("field strength")  # the header comment closes where it should
