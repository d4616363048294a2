"""The declared unit checked against the Earth's field before an export writes the field in a unit.

Reproducers: a QMC5883L recording in raw counts declared uT fits a field of about 1070 "uT" (the Adafruit
header would say ``mag_field = 1071.19f``); the FXOS8700 recording converted to tesla and declared uT fits
5.3e-05 "uT". Every export that writes the field in a physical unit refuses both with the code
``unit_mismatch`` and the likely unit as its remedy, unless ``allow_unit_mismatch``.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

import magfit
from magfit.errors import ExportError
from magfit.export import UNIT_CHECKED, export, export_several


@pytest.fixture(scope="module")
def counts_as_ut(real_data_dir: Path) -> magfit.Calibration:
    samples = np.loadtxt(real_data_dir / "unc_qmc5883l" / "filtered_raw_data.csv", delimiter=",", skiprows=3)[3000:]
    return magfit.fit(samples, method="ellipsoid").with_unit("uT")


@pytest.fixture(scope="module")
def tesla_as_ut(real_data_dir: Path) -> magfit.Calibration:
    samples = 1e-6 * np.loadtxt(real_data_dir / "fxos8700_magneto" / "mag-readings.txt")  # uT -> T
    return magfit.fit(samples, method="ellipsoid").with_unit("uT")


@pytest.mark.parametrize("name", UNIT_CHECKED)
def test_counts_declared_ut_are_refused_naming_counts(name: str, counts_as_ut: magfit.Calibration) -> None:
    assert 1000 < counts_as_ut.field_strength < 1100
    with pytest.raises(ExportError) as refused:
        export(counts_as_ut, name)
    assert refused.value.codes == ("unit_mismatch",) and refused.value.remedy == (("unit", "counts"),)
    assert "raw counts" in str(refused.value)


@pytest.mark.parametrize("name", UNIT_CHECKED)
def test_tesla_declared_ut_is_refused_naming_tesla(name: str, tesla_as_ut: magfit.Calibration) -> None:
    with pytest.raises(ExportError) as refused:
        export(tesla_as_ut, name)
    assert refused.value.codes == ("unit_mismatch",) and refused.value.remedy == (("unit", "T"),)
    # Declared as what it is, it is written; the Adafruit field then is the recording's, in uT.
    text = export(tesla_as_ut, name, unit="T")
    if name == "adafruit":
        field = float(re.search(r"mag_field = ([\d.e+-]+)f;", text).group(1))  # type: ignore[union-attr]
        assert field == pytest.approx(1e6 * tesla_as_ut.field_strength, rel=1e-8)
        assert 45 < field < 60


def test_forced_writes_the_values_as_declared_and_says_so(counts_as_ut: magfit.Calibration) -> None:
    text = export(counts_as_ut, "adafruit", allow_unit_mismatch=True)
    field = float(re.search(r"mag_field = ([\d.e+-]+)f;", text).group(1))  # type: ignore[union-attr]
    assert field == pytest.approx(counts_as_ut.field_strength, rel=1e-8)
    assert text.splitlines()[1].startswith(" * WARNING (written although): the fitted field strength")
    for name in UNIT_CHECKED:
        forced = export(counts_as_ut, name, allow_unit_mismatch=True)
        assert ("WARNING (written although)" in forced) == (name != "adafruit-json")  # JSON has no comments


def test_the_way_to_write_it_all_the_same_is_said_in_the_readers_words(counts_as_ut: magfit.Calibration) -> None:
    from magfit.remedy import for_command_line

    with pytest.raises(ExportError, match=r"write it all the same \(allow_unit_mismatch=True\)"):
        export(counts_as_ut, "adafruit")
    with for_command_line(), pytest.raises(ExportError, match=r"write it all the same \(--force\)"):
        export(counts_as_ut, "adafruit")


@pytest.mark.parametrize("name", ["json", "magcal"])
def test_formats_naming_no_unit_or_lossless_are_not_checked(name: str, counts_as_ut: magfit.Calibration) -> None:
    assert export(counts_as_ut, name)


@pytest.mark.parametrize(("name", "limit"), [("ardupilot", "Check mag field"), ("px4", "sphere radius")])
def test_firmware_field_refusals_name_the_likely_unit(
    name: str, limit: str, tesla_as_ut: magfit.Calibration, counts_as_ut: magfit.Calibration
) -> None:
    for cal, likely in ((tesla_as_ut, "T"), (counts_as_ut, "counts")):
        with pytest.raises(ExportError, match=limit) as refused:
            export(cal, name)
        assert refused.value.codes == ("unit_mismatch",) and refused.value.remedy == (("unit", likely),)
    with pytest.raises(ExportError) as refused:
        export_several([tesla_as_ut], name)
    assert refused.value.codes == ("unit_mismatch",)


def test_a_plausible_field_passes_every_checked_format() -> None:
    cal = magfit.Calibration("test", np.array([1.0, -2.0, 3.0]), np.eye(3), 48.0, unit="uT")
    for name in UNIT_CHECKED:
        assert export(cal, name)
    as_gauss = magfit.Calibration("test", np.zeros(3), np.eye(3), 0.48, unit="G")
    for name in UNIT_CHECKED:
        assert export(as_gauss, name)
