"""magfit.geomag: the World Magnetic Model against its authors' published test values; places, dates, units."""

from __future__ import annotations

import datetime as dt
import re
import sys

import numpy as np
import pytest

from magfit import geomag
from magfit.errors import OptionError
from magfit.geomag import decimal_year, field_at, parse_date, parse_location

pytest.importorskip("pygeomag", reason="the wmm extra is not installed")

# The WMM2025 test values of NOAA NCEI and BGS, WMM2025_TEST_VALUES.txt in WMM2025COF.zip (released with the
# coefficients on 2024-12-17): decimal year, height above the WGS-84 ellipsoid (km), geodetic latitude and
# longitude (degrees); X (north), Y (east), Z (down) in nT, inclination and declination in degrees. The values
# are printed to 0.1 nT and 0.01 degree.
WMM2025_TEST_VALUES = [
    (2025.0, 0.0, 80.0, 0.0, 6521.6, 145.9, 54791.5, 83.21, 1.28),
    (2025.0, 0.0, 0.0, 120.0, 39677.8, -109.6, -10580.2, -14.93, -0.16),
    (2025.0, 0.0, -80.0, 240.0, 6117.5, 15751.9, -52022.5, -72.00, 68.78),
    (2025.0, 100.0, 80.0, 0.0, 6216.0, 92.4, 52598.8, 83.26, 0.85),
    (2025.0, 100.0, 0.0, 120.0, 37688.6, -96.2, -10152.1, -15.08, -0.15),
    (2025.0, 100.0, -80.0, 240.0, 5907.6, 14780.3, -49540.7, -72.19, 68.21),
    (2027.5, 0.0, 80.0, 0.0, 6500.8, 294.5, 54869.4, 83.24, 2.59),
    (2027.5, 0.0, 0.0, 120.0, 39701.6, -167.4, -10381.8, -14.65, -0.24),
    (2027.5, 0.0, -80.0, 240.0, 6200.7, 15730.3, -51783.7, -71.92, 68.49),
    (2027.5, 100.0, 80.0, 0.0, 6196.7, 233.8, 52670.5, 83.29, 2.16),
    (2027.5, 100.0, 0.0, 120.0, 37711.5, -148.7, -9969.8, -14.81, -0.23),
    (2027.5, 100.0, -80.0, 240.0, 5984.0, 14760.1, -49317.7, -72.10, 67.93),
]

# The four rows the README of WMM2025COF.zip ("2. Installation Verification") prints with H and F as well:
# year, height (km), latitude, longitude, H, F (nT).
WMM2025_README_H_F = [
    (2025.0, 0.0, 80.0, 0.0, 6523.2, 55178.5),
    (2025.0, 0.0, -80.0, 240.0, 16898.1, 54698.2),
    (2027.5, 100.0, 80.0, 0.0, 6201.1, 53034.3),
    (2027.5, 100.0, -80.0, 240.0, 15927.0, 51825.7),
]

#: Half the last printed digit, and a hair for the rounding of the printed value itself.
NT_TOLERANCE = 0.05 + 1e-6
DEG_TOLERANCE = 0.005 + 1e-9


@pytest.mark.parametrize(("year", "alt", "lat", "lon", "x", "y", "z", "inc", "dec"), WMM2025_TEST_VALUES)
def test_the_published_wmm2025_test_values(
    year: float, alt: float, lat: float, lon: float, x: float, y: float, z: float, inc: float, dec: float
) -> None:
    field = field_at(lat, lon, alt_km=alt, date=year)
    assert field.model == "WMM-2025"
    assert abs(field.north - x) <= NT_TOLERANCE
    assert abs(field.east - y) <= NT_TOLERANCE
    assert abs(field.down - z) <= NT_TOLERANCE
    assert abs(field.inclination_deg - inc) <= DEG_TOLERANCE
    assert abs(field.declination_deg - dec) <= DEG_TOLERANCE


@pytest.mark.parametrize(("year", "alt", "lat", "lon", "h", "f"), WMM2025_README_H_F)
def test_the_published_horizontal_and_total_intensities(
    year: float, alt: float, lat: float, lon: float, h: float, f: float
) -> None:
    field = field_at(lat, lon, alt_km=alt, date=year)
    assert abs(field.horizontal - h) <= NT_TOLERANCE
    assert abs(field.total - f) <= NT_TOLERANCE
    # The components agree with each other (one formula, not the package's word for it).
    assert field.total == pytest.approx(np.hypot(field.horizontal, field.down), rel=1e-12)
    assert field.horizontal == pytest.approx(np.hypot(field.north, field.east), rel=1e-12)
    assert np.degrees(np.arctan2(field.down, field.horizontal)) == pytest.approx(field.inclination_deg, abs=1e-9)


def test_units_and_the_uncertainty() -> None:
    field = field_at(80.0, 0.0, date=2025.0)
    assert field.total_in("nT") == field.total
    assert field.total_in("uT") == pytest.approx(field.total / 1000, rel=1e-15)
    assert field.total_in("G") == pytest.approx(field.total / 1e5, rel=1e-15)
    assert field.total_in("mG") == pytest.approx(field.total / 100, rel=1e-15)
    np.testing.assert_allclose(field.vector_in("T"), np.array([field.north, field.east, field.down]) * 1e-9)
    assert field.total_uncertainty == 138.0  # WMM2025's published global error of F (nT)
    with pytest.raises(OptionError, match="raw counts"):
        field.total_in("counts")
    with pytest.raises(OptionError, match="unknown unit"):
        field.total_in("furlongs")


def test_longitudes_past_180_are_the_same_place() -> None:
    east, west = field_at(-80.0, 240.0, date=2025.0), field_at(-80.0, -120.0, date=2025.0)
    assert (east.north, east.east, east.down) == pytest.approx((west.north, west.east, west.down), abs=1e-9)
    assert east.longitude == -120.0


def test_each_date_gets_the_model_of_its_time() -> None:
    assert field_at(47.4, 8.5, date=2022.5).model == "WMM-2020"
    assert field_at(47.4, 8.5, date=2017.0).model.startswith("WMM-2015")
    assert field_at(47.4, 8.5, date=dt.date(2026, 6, 1)).model == "WMM-2025"
    assert field_at(47.4, 8.5).model == "WMM-2025"  # today
    with pytest.raises(OptionError, match=r"no World Magnetic Model covers 2030\.50.*newer pygeomag"):
        field_at(47.4, 8.5, date=2030.5)
    with pytest.raises(OptionError, match=r"covers 2009\.00"):
        field_at(47.4, 8.5, date="2009-01-01")


def test_decimal_years_count_days_as_the_model_software_does() -> None:
    assert decimal_year(dt.date(2025, 1, 1)) == 2025.0
    assert decimal_year(dt.date(2020, 7, 2)) == 2020.5  # day 183 of a leap year's 366
    assert decimal_year("2027-07-02") == pytest.approx(2027 + 182 / 365)
    noon = dt.datetime(2025, 1, 2, 12, tzinfo=dt.timezone.utc)
    assert decimal_year(noon) == pytest.approx(2025 + 1.5 / 365)
    assert decimal_year(dt.datetime(2025, 1, 2, 13, tzinfo=dt.timezone(dt.timedelta(hours=1)))) == decimal_year(noon)
    assert decimal_year(2026.25) == 2026.25
    with pytest.raises(OptionError, match="YYYY-MM-DD"):
        decimal_year("June 2026")
    with pytest.raises(OptionError, match="finite"):
        decimal_year(float("nan"))


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("47.4,8.5", (47.4, 8.5, 0.0)),
        (" 47.4 , 8.5 , 0.5 ", (47.4, 8.5, 0.5)),
        ("47.4,8.5,500m", (47.4, 8.5, 0.5)),
        ("-33.9,151.2,0.05km", (-33.9, 151.2, 0.05)),
        ("-80,240", (-80.0, 240.0, 0.0)),
    ],
)
def test_locations(text: str, expected: tuple[float, float, float]) -> None:
    assert parse_location(text) == pytest.approx(expected)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("47.4", "LAT,LON"),
        ("47.4,8.5,0.5,1", "LAT,LON"),
        ("north,8.5", "decimal degrees"),
        ("91,8.5", "latitude must be between -90 and 90"),
        ("47.4,400", "longitude must be between"),
        ("47.4,8.5,high", "altitude must be a number"),
        ("47.4,8.5,900", "between -1 and 850 km"),
        ("nan,8.5", "latitude"),
    ],
)
def test_bad_locations_are_named(text: str, message: str) -> None:
    with pytest.raises(OptionError, match=message):
        parse_location(text)


def test_dates() -> None:
    assert parse_date("2026-06-01") == dt.date(2026, 6, 1)
    with pytest.raises(OptionError, match="2026-13-01"):
        parse_date("2026-13-01")


def test_a_missing_extra_is_the_install_command(monkeypatch: pytest.MonkeyPatch) -> None:
    geomag._model.cache_clear()
    monkeypatch.setitem(sys.modules, "pygeomag", None)  # import pygeomag now raises ImportError
    try:
        with pytest.raises(ImportError, match=r"pip install 'magfit\[wmm\]'") as caught:
            field_at(47.4, 8.5, date=2026.0)
        assert caught.value.name == "pygeomag"
    finally:
        geomag._model.cache_clear()


def test_importing_magfit_does_not_import_the_model() -> None:
    import subprocess

    code = "import magfit, magfit.geomag, sys; print('pygeomag' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


# ---------------------------------------------------------------------- the command line

ZURICH = "47.4,8.5,0.5"
DATE = "2026-06-01"


def _recording(tmp_path, field_ut: float, name: str = "mag.csv"):
    """The paper's Ellipse 2A with steel, scaled so that its field is ``field_ut`` (µT), as a CSV."""
    import magfit

    simulation = magfit.scenario("ellipse2a", "steel").simulate(2000, seed=5)
    path = tmp_path / name
    # Scaled by the field an ellipsoid fit finds (the geometric mean of the semi-axes: the steel shrinks it).
    samples = simulation.samples * (field_ut / magfit.fit(simulation.samples, method="ellipsoid").field_strength)
    np.savetxt(path, samples, fmt="%.17g", delimiter=",", header="mx,my,mz", comments="")
    return path


def _run(*args: str):
    from click.testing import CliRunner

    from magfit.cli import cli

    return CliRunner().invoke(cli, list(args))


def test_calibrate_pins_the_field_to_the_model(tmp_path) -> None:
    import magfit

    expected = field_at(47.4, 8.5, alt_km=0.5, date=DATE).total_in("uT")
    path = _recording(tmp_path, 50.0)
    output = tmp_path / "cal.json"
    result = _run(
        "calibrate", str(path), "--unit", "uT", "--field-strength", "wmm", "--location", ZURICH, "--date", DATE,
        "-m", "ellipsoid", "-o", str(output),
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    calibration = magfit.Calibration.from_json(output.read_text())
    assert calibration.field_strength == expected  # the model's number, exactly
    corrected = np.linalg.norm(calibration.apply(np.loadtxt(path, delimiter=",", skiprows=1)), axis=1)
    assert np.median(corrected) == pytest.approx(expected, rel=0.01)
    assert "used as the field strength (the samples alone: 50" in result.stdout
    assert "warning" not in result.stderr  # 50 against 48.4 µT: 3 %, within the 10 % warning threshold


def test_calibrate_prints_the_model_beside_the_fit_and_warns_when_far(tmp_path) -> None:
    near = _run("calibrate", str(_recording(tmp_path, 49.0)), "--unit", "uT", "--location", ZURICH, "--date", DATE)
    assert near.exit_code == 0, near.output
    assert "model field      48.3798 ± 0.14 uT (WMM-2025 at 47.4°, 8.5°, 0.5 km on 2026.41" in near.stdout
    assert "warning" not in near.stderr
    far = _run("calibrate", str(_recording(tmp_path, 40.0, "far.csv")), "--unit", "uT", "--location", ZURICH)
    assert far.exit_code == 0, far.output
    assert "-17 % off the World Magnetic Model's" in far.stderr and "steel or magnets near the sensor" in far.stderr
    wrong_unit = _run("calibrate", str(_recording(tmp_path, 0.49, "gauss.csv")), "--unit", "uT", "--location", ZURICH)
    assert wrong_unit.exit_code == 0, wrong_unit.output
    assert "the samples look like G, not uT" in wrong_unit.stderr
    unknown = _run("calibrate", str(_recording(tmp_path, 49.0, "counts.csv")), "--location", ZURICH)
    assert unknown.exit_code == 0 and "not compared with the fit: the samples' unit is unknown" in unknown.stdout


def test_a_model_field_the_samples_contradict_is_refused(tmp_path) -> None:
    # Samples in gauss labelled µT, pinned to the model: the fit's verdict refuses (exit 1), naming the mix-up.
    path = _recording(tmp_path, 0.484)
    result = _run("calibrate", str(path), "--unit", "uT", "--field-strength", "wmm", "--location", ZURICH)
    assert result.exit_code == 1, result.output
    assert "unit mix-up" in result.stderr and "Traceback" not in result.output


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--unit", "uT", "--field-strength", "wmm"], "--field-strength wmm needs --location"),
        (["--field-strength", "wmm", "--location", ZURICH], "needs the samples' physical unit"),
        (["--unit", "counts", "--field-strength", "wmm", "--location", ZURICH], "raw counts have no known scale"),
        (["--unit", "uT", "--date", DATE], "--date goes with --location"),
        (["--unit", "uT", "--location", "47.4"], "expected a location as LAT,LON"),
        (["--unit", "uT", "--location", ZURICH, "--date", "01/06/2026"], "YYYY-MM-DD"),
        (["--unit", "uT", "--location", ZURICH, "--date", "2031-01-01"], "no World Magnetic Model covers 2031.00"),
        (["--unit", "uT", "--field-strength", "-3"], "a positive number .* or 'wmm'"),
    ],
)
def test_bad_model_options_are_usage_errors(tmp_path, args: list[str], message: str) -> None:
    path = _recording(tmp_path, 48.0)
    output = tmp_path / "cal.json"
    output.write_text("kept")
    result = _run("calibrate", str(path), "-o", str(output), *args)
    assert result.exit_code == 2, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("magfit: error: ")
    assert re.search(message, lines[0]), lines[0]
    assert output.read_text() == "kept"


def test_the_cli_without_the_extra_names_the_install_command(tmp_path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = _recording(tmp_path, 48.0)
    geomag._model.cache_clear()
    monkeypatch.setitem(sys.modules, "pygeomag", None)
    try:
        result = _run("calibrate", str(path), "--unit", "uT", "--location", ZURICH)
    finally:
        geomag._model.cache_clear()
    assert result.exit_code == 2, result.output
    assert result.stderr.strip() == (
        "magfit: error: the World Magnetic Model needs pygeomag, which is not installed (the wmm extra): "
        "pip install 'magfit[wmm]'"
    )
