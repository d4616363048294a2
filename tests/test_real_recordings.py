"""The paper's three methods on every real recording in ../shared/data/real (see its README).

The files are read here with plain pandas calls that spell out each layout, so these tests check the
methods, not the file readers (magfit.io has its own tests on the same files).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import magfit
from magfit import CalibrationError

PAPER_METHODS = ("ellipsoid", "sphere", "minmax")


def load(folder: Path, name: str) -> np.ndarray:
    """The magnetometer columns of each recording, as its README describes the layout."""
    layouts: dict[str, tuple[str, dict, list[str] | None]] = {
        "fxos": ("fxos8700_magneto/mag-readings.txt", {"sep": "\t", "header": None}, None),
        "unc": ("unc_qmc5883l/filtered_raw_data.csv", {"skiprows": 2}, ["mx", "my", "mz"]),
        "betaflight03": (
            "betaflight_apex5_qmc5883/20231014_apex5_mag_on_tpu_03.txt",
            {"sep": ",", "header": None},
            None,
        ),
        "betaflight00": (
            "betaflight_apex5_qmc5883/20231008_apex5_mag_on_tpu_00.txt",
            {"sep": ",", "header": None},
            None,
        ),
        "mxl_imu": ("mxl_umich_mpu9250_rm3100/preflight_data_original_imu.csv", {"encoding": "utf-8-sig"}, None),
        "mxl_pni": ("mxl_umich_mpu9250_rm3100/preflight_data_original_pni.csv", {"encoding": "utf-8-sig"}, None),
        "mxl_drone": ("mxl_umich_mpu9250_rm3100/test0_esti_trunc.csv", {}, None),
        "animal_calib": ("animaltrack_missionbay/missionbay_calib2_converted.csv", {}, ["mx_raw", "my_raw", "mz_raw"]),
        "animal_track": ("animaltrack_missionbay/missionbay2_converted.csv", {}, ["mx_raw", "my_raw", "mz_raw"]),
        "gyrolib": ("gyrolib_rahrs/calibrationGyroLib_converted.csv", {}, ["Mx", "My", "Mz"]),
        "hamagure1": ("hamagure_gauss/data-set_1.csv", {}, None),
        "hamagure2": ("hamagure_gauss/data-set_2.csv", {}, None),
        "ensta": ("ensta_tlefloch_imu/mag_data.txt", {"sep": r"\s+", "header": None}, None),
        "android": ("android_phone_kritiksoman/data_mag.txt", {}, ["x", "y", "z"]),
        "hmc5883l": ("hmc5883l_nliaudat_partial/mag_out_sample.txt", {"header": None}, None),
    }
    path, options, columns = layouts[name]
    frame = pd.read_csv(folder / path, **options)
    samples = (frame[columns] if columns else frame.iloc[:, :3]).to_numpy(dtype=float)
    return samples[np.isfinite(samples).all(axis=1)]


GOOD = ["fxos", "unc", "betaflight03", "betaflight00", "mxl_imu", "mxl_pni", "mxl_drone", "animal_calib",
        "animal_track", "gyrolib", "hamagure1", "hamagure2", "ensta"]  # fmt: skip
FAILURES = ["android", "hmc5883l"]


#: The recordings on which a method is refused, and the reason it must give (the support verdict). Min/max
#: centred on the mean of samples that do not cover the sphere evenly leaves 16-76 % residuals where the
#: full ellipsoid leaves 0.4-4 %; a sphere on the QMC5883L's strong soft iron (semi-axis ratio 2.2) leaves
#: 16 %. (The second Hamagure set covers only the z < 0 half: the full model's z scale is not determined apart
#: from its z offset, but the level heading is, to ±2°: returned, weak, saying so — see below.)
REFUSED = {
    ("sphere", "unc"): "cannot describe these samples",
    # The full ellipsoid on the same samples leaves significantly less (F test) and pins a level heading
    # more than 3° away from the restricted fit's: soft iron the restricted model cannot hold.
    **{("sphere", name): "soft iron this model cannot remove" for name in ("mxl_pni", "animal_calib", "animal_track")},
    **{("minmax", name): "soft iron this model cannot remove" for name in ("fxos", "betaflight03", "betaflight00")},
    **{
        ("minmax", name): "cannot describe these samples|biased"
        for name in (
            "unc", "mxl_imu", "mxl_pni", "mxl_drone", "animal_calib", "animal_track", "gyrolib", "hamagure1",
            "hamagure2", "ensta",
        )
    },
}  # fmt: skip


@pytest.mark.parametrize("name", GOOD)
@pytest.mark.parametrize("method", PAPER_METHODS)
@pytest.mark.slow
def test_every_recording_calibrates_or_is_refused_with_its_reason(real_data_dir: Path, name: str, method: str) -> None:
    samples = load(real_data_dir, name)
    reason = REFUSED.get((method, name))
    if reason is not None:
        with pytest.raises(CalibrationError, match=reason):
            magfit.fit(samples, method=method)
        cal = magfit.fit(samples, method=method, allow_undetermined=True)  # forced: returned, with the refusal
        assert cal.support.forced and cal.diagnostics is not None
        assert any(w.startswith("NOT SUPPORTED") for w in cal.diagnostics.warnings)
        return
    cal = magfit.fit(samples, method=method)
    result = magfit.evaluate(cal, samples)
    assert np.all(np.isfinite(cal.matrix)) and cal.field_strength > 0
    assert cal.support.verdict in ("supported", "weak")
    # Calibrated samples lie near the unit sphere: within 45 % even for min/max on strong soft iron.
    assert abs(result.mean) < 0.7 and result.std < 0.45
    if method == "ellipsoid":  # the full model fits every real recording to a few percent
        assert result.std < 0.05


def test_a_half_covered_recording_holds_only_near_the_attitudes_recorded(real_data_dir: Path) -> None:
    cal = magfit.fit(load(real_data_dir, "hamagure2"), method="ellipsoid")
    assert cal.diagnostics is not None and cal.diagnostics.support is not None
    assert cal.diagnostics.support.verdict == "weak"
    first = cal.diagnostics.support.weaknesses[0]
    assert "do not determine the scale along z" in first and "holds only near the attitudes recorded" in first


@pytest.mark.parametrize("name", FAILURES)
@pytest.mark.parametrize("method", PAPER_METHODS)
def test_failure_cases_get_a_diagnosis_not_numbers(real_data_dir: Path, name: str, method: str) -> None:
    reasons = "not an ellipsoid|do not outline an ellipsoid|no ellipsoid|only turned about|close to a plane"
    with pytest.raises(CalibrationError, match=reasons) as caught:
        magfit.fit(load(real_data_dir, name), method=method)
    assert any(remedy in str(caught.value) for remedy in ("rotat", "turning", "tilt"))  # it says what to do


@pytest.mark.parametrize("name", FAILURES)
@pytest.mark.parametrize("method", sorted(name for name, spec in magfit.METHODS.items() if not spec.needs))
@pytest.mark.slow
def test_failure_cases_get_a_diagnosis_from_every_method(real_data_dir: Path, name: str, method: str) -> None:
    with pytest.raises(CalibrationError) as caught:
        magfit.fit(load(real_data_dir, name), method=method)
    message = str(caught.value)
    assert any(remedy in message for remedy in ("rotat", "turning", "tilt", "attitudes")), message


def test_fxos8700_agrees_with_the_published_magneto_result(real_data_dir: Path) -> None:
    cal = magfit.fit(load(real_data_dir, "fxos"), method="ellipsoid")
    magneto_offset = np.array([28.557458, -39.981060, -27.428035])
    magneto_matrix = np.array(
        [[0.989575, -0.022220, 0.005152], [-0.022220, 0.989327, 0.022216], [0.005152, 0.022216, 1.045404]]
    )
    assert np.linalg.norm(cal.offset - magneto_offset) < 0.5  # µT
    # Magneto's A is scaled to its own field norm: compare the shapes, scale removed.
    shape = cal.matrix / np.cbrt(np.linalg.det(cal.matrix))
    published = magneto_matrix / np.cbrt(np.linalg.det(magneto_matrix))
    np.testing.assert_allclose(shape, published, atol=0.01)


def test_betaflight_hard_iron_agrees_with_the_flight_controller(real_data_dir: Path) -> None:
    # The README gives the flight controller's own hard-iron result for tpu_03: (957, 417, 502) counts.
    cal = magfit.fit(load(real_data_dir, "betaflight03"), method="sphere")
    assert np.linalg.norm(cal.offset - [957, 417, 502]) < 0.02 * cal.field_strength
