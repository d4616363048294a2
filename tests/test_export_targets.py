"""The new export targets of issue 12, each parsed and applied the way its consumer does.

Every consumer's formula is re-implemented here from its source (cited per test, independently of
magfit/export), applied to the exported text on a real recording, and compared with
``Calibration.apply`` after the consumer's unit conversion:

- Adafruit_Sensor_Calibration 80dfeba: ``calibrate()`` and ``Adafruit_Sensor_Calibration_SDFat::loadCalibration``;
- INAV 005b1ee ``compassUpdate`` (integer arithmetic) and settings.yaml's int16 settings;
- Betaflight 58ae3fd / 0270127 ``compassUpdate`` and the CLI settings table's ``mag_calibration`` (settings.c);
- RTIMULib 6a6e784 ``RTIMUSettings::loadSettings``, ``RTIMU::setCalibrationData`` and ``calibrateAverageCompass``;
- imu_tools (humble c8a27cd) ``ImuFilterRos::imuMagCallback``.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import yaml
from numpy.typing import NDArray

import magfit
from magfit.errors import ExportError
from magfit.export import FORMATS, export

NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
#: float32 text (9 digits) and float32 arithmetic on the consumers' side, relative to max|raw|.
RTOL_FLOAT32 = 2e-6


def _fxos(real_data_dir: Path) -> NDArray[np.float64]:
    # NXP FXOS8700, µT, tab-separated x y z, no header.
    return np.loadtxt(real_data_dir / "fxos8700_magneto" / "mag-readings.txt")


def _hamagure(real_data_dir: Path) -> NDArray[np.float64]:
    # Unknown sensor, gauss, header x,y,z.
    return np.loadtxt(real_data_dir / "hamagure_gauss" / "data-set_1.csv", delimiter=",", skiprows=1)


def _apex5(real_data_dir: Path) -> NDArray[np.float64]:
    # QMC5883 on a Betaflight quadcopter, raw int16 counts: mx, my, mz, gx, gy, gz.
    path = real_data_dir / "betaflight_apex5_qmc5883" / "20231014_apex5_mag_on_tpu_03.txt"
    return np.loadtxt(path, delimiter=",")[:, :3]


def _unc(real_data_dir: Path) -> NDArray[np.float64]:
    # QMC5883L, raw counts, strong soft iron (semi-axes about 1084 / 709 / 1598); 60 s warm-up at 50 Hz.
    return np.loadtxt(real_data_dir / "unc_qmc5883l" / "filtered_raw_data.csv", delimiter=",", skiprows=3)[3000:]


@pytest.fixture(scope="module", params=["fxos8700_uT", "hamagure_G", "fxos8700_uT_cholesky"])
def physical(
    request: pytest.FixtureRequest, real_data_dir: Path
) -> tuple[magfit.Calibration, NDArray[np.float64], float]:
    """(calibration, samples, µT per sample unit) for a µT and a gauss recording, and a non-symmetric matrix."""
    if request.param == "hamagure_G":
        samples = _hamagure(real_data_dir)
        return magfit.fit(samples, method="ellipsoid").with_unit("G"), samples, 100.0
    samples = _fxos(real_data_dir)
    root = "cholesky" if request.param.endswith("cholesky") else "sqrt"
    return magfit.fit(samples, method="ellipsoid", root=root).with_unit("uT"), samples, 1.0


def _close(actual: NDArray[np.float64], expected: NDArray[np.float64], raw: NDArray[np.float64], rtol: float) -> None:
    np.testing.assert_allclose(actual, expected, rtol=0, atol=rtol * float(np.max(np.abs(raw))))


def _level_heading_error(cal: magfit.Calibration, matrix: NDArray[np.float64], offset: NDArray[np.float64]) -> float:
    """Worst heading error of ``matrix @ (raw - offset)``, sensor level, inclinations up to ±70° (a coarse grid)."""
    inc, head = np.meshgrid(np.radians(np.arange(-70, 71, 5.0)), np.radians(np.arange(0, 360, 2.0)))
    field = cal.field_strength * np.stack([np.cos(inc) * np.cos(head), np.cos(inc) * np.sin(head), np.sin(inc)], -1)
    field = field.reshape(-1, 3)
    raw = field @ np.linalg.inv(cal.matrix).T + cal.offset
    seen = (raw - offset) @ matrix.T
    error = np.arctan2(seen[:, 1], seen[:, 0]) - np.arctan2(field[:, 1], field[:, 0])
    return float(np.degrees(np.max(np.abs((error + np.pi) % (2 * np.pi) - np.pi))))


def _stated_loss(text: str) -> float:
    return float(re.search(r"heading error of up to ([\d.]+) deg", text).group(1))  # type: ignore[union-attr]


# ---------------------------------------------------------------------- Adafruit_Sensor_Calibration


def adafruit_calibrate(hard: list[float], soft: list[float], magnetic_ut: NDArray[np.float64]) -> NDArray[np.float64]:
    """Adafruit_Sensor_Calibration::calibrate: m = magnetic - hardiron; out[i] = sum_j softiron[3i + j] m[j]."""
    m = magnetic_ut - np.asarray(hard)
    s = np.asarray(soft)
    return np.stack([m @ s[0:3], m @ s[3:6], m @ s[6:9]], axis=1)


def test_adafruit_header_applied_by_calibrate_gives_apply_in_ut(
    physical: tuple[magfit.Calibration, NDArray[np.float64], float],
) -> None:
    cal, samples, k = physical
    text = export(cal, "adafruit").split("#if defined(ADAFRUIT_SENSOR_CALIBRATION_USE_EEPROM)")[0]  # as fitted
    values: dict[str, dict[int, float]] = {"mag_hardiron": {}, "mag_softiron": {}}
    for name, index, value in re.findall(rf"cal\.(mag_\w+)\[(\d)\] = ({NUMBER})f;", text):
        values[name][int(index)] = float(value)
    field = float(re.search(rf"cal\.mag_field = ({NUMBER})f;", text).group(1))  # type: ignore[union-attr]
    hard = [values["mag_hardiron"][i] for i in range(3)]
    soft = [values["mag_softiron"][i] for i in range(9)]
    _close(adafruit_calibrate(hard, soft, k * samples), k * cal.apply(samples), k * samples, 1e-7)
    assert field == pytest.approx(k * cal.field_strength, rel=1e-8)
    assert ("WARNING: the matrix is a Cholesky root" in text) == (cal.details.get("root") == "cholesky")


def test_adafruit_header_compiles_as_cpp(tmp_path: Path, real_data_dir: Path) -> None:
    # The members the header sets, declared as in Adafruit_Sensor_Calibration.h (80dfeba): public float
    # arrays of 3 and 9 and a float. calibrate() re-implemented in C++ reads them back.
    compiler = shutil.which("g++")
    if compiler is None:
        pytest.skip("no g++")
    samples = _fxos(real_data_dir)
    cal = magfit.fit(samples, method="ellipsoid", root="cholesky").with_unit("uT")
    (tmp_path / "Adafruit_Sensor_Calibration.h").write_text(
        "class Adafruit_Sensor_Calibration {\npublic:\n  float mag_hardiron[3] = {0, 0, 0};\n"
        "  float mag_softiron[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};\n  float mag_field = 50;\n};\n"
    )
    (tmp_path / "cal.h").write_text(export(cal, "adafruit"))
    (tmp_path / "main.cpp").write_text(
        '#include <cstdio>\n#include "cal.h"\nint main() {\n  Adafruit_Sensor_Calibration cal;\n'
        "  magfit_set_calibration(cal);\n  float x, y, z;\n"
        '  while (std::scanf("%f %f %f", &x, &y, &z) == 3) {\n'
        "    float mx = x - cal.mag_hardiron[0], my = y - cal.mag_hardiron[1], mz = z - cal.mag_hardiron[2];\n"
        '    std::printf("%.9g %.9g %.9g\\n",\n'
        "      mx * cal.mag_softiron[0] + my * cal.mag_softiron[1] + mz * cal.mag_softiron[2],\n"
        "      mx * cal.mag_softiron[3] + my * cal.mag_softiron[4] + mz * cal.mag_softiron[5],\n"
        "      mx * cal.mag_softiron[6] + my * cal.mag_softiron[7] + mz * cal.mag_softiron[8]);\n  }\n}\n"
    )
    exe = tmp_path / "main"
    build = subprocess.run(
        [compiler, "-std=c++11", "-Wall", "-Wextra", "-Werror", "-I", str(tmp_path), str(tmp_path / "main.cpp"),
         "-o", str(exe)],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert build.returncode == 0, build.stderr
    stdin = "\n".join(" ".join(f"{v:.9g}" for v in row) for row in samples)
    out = np.loadtxt(
        subprocess.run([str(exe)], input=stdin, capture_output=True, text=True, check=True).stdout.splitlines()
    )
    _close(out, cal.apply(samples), samples, RTOL_FLOAT32)


def test_adafruit_json_loaded_as_the_sdfat_library_does(
    physical: tuple[magfit.Calibration, NDArray[np.float64], float],
) -> None:
    cal, samples, k = physical
    data = json.loads(export(cal, "adafruit-json"))
    # loadCalibration reads exactly these keys (absent ones default: hardiron 0, softiron identity, field 0).
    assert set(data) == {"mag_hardiron", "mag_softiron", "mag_field"}
    hard = [data["mag_hardiron"][i] if i < len(data["mag_hardiron"]) else 0.0 for i in range(3)]
    soft = [data["mag_softiron"][i] for i in range(9)]
    # ArduinoJson stores the numbers as float on the microcontroller.
    hard32 = np.float32(hard).astype(np.float64)
    soft32 = np.float32(soft).astype(np.float64)
    _close(
        adafruit_calibrate(list(hard32), list(soft32), k * samples), k * cal.apply(samples), k * samples, RTOL_FLOAT32
    )
    assert data["mag_field"] == pytest.approx(k * cal.field_strength, rel=1e-12)


@pytest.mark.parametrize("name", ["adafruit", "adafruit-json", "rtimulib", "ros-madgwick"])
def test_microtesla_and_tesla_targets_refuse_counts(name: str) -> None:
    cal = magfit.Calibration("test", np.zeros(3), np.eye(3), 1400.0, unit="counts")
    with pytest.raises(ExportError, match="raw counts of unknown scale"):
        export(cal, name)


# ---------------------------------------------------------------------- INAV


def parse_cli(text: str) -> dict[str, str]:
    """``set name = value`` lines of an INAV / Betaflight CLI script (``#`` comments, ``save``)."""
    settings = {}
    for line in text.splitlines():
        if line.startswith("set "):
            name, value = line[4:].split(" = ")
            settings[name] = value
    assert text.rstrip().endswith("\nsave")
    return settings


def inav_correct(settings: dict[str, str], raw: NDArray[np.float64]) -> NDArray[np.float64]:
    """INAV compassUpdate: magADC = (magADCRaw - magZero) * 1024 / magGain, int32 arithmetic (C truncates)."""
    zero = np.array([int(settings[f"magzero_{a}"]) for a in "xyz"], dtype=np.int64)
    gain = np.array([int(settings[f"maggain_{a}"]) for a in "xyz"], dtype=np.int64)
    scaled = (raw.astype(np.int64) - zero) * 1024
    return (np.sign(scaled) * (np.abs(scaled) // gain)).astype(np.float64)  # C division truncates toward zero


@pytest.mark.parametrize("recording", ["apex5", "unc"])
def test_inav_correction_is_the_diagonal_of_apply_and_says_what_it_loses(recording: str, real_data_dir: Path) -> None:
    samples = _apex5(real_data_dir) if recording == "apex5" else _unc(real_data_dir)
    cal = magfit.fit(samples, method="ellipsoid").with_unit("counts")
    text = export(cal, "inav")
    settings = parse_cli(text)
    assert list(settings) == [f"mag{kind}_{a}" for kind in ("zero", "gain") for a in "xyz"]
    corrected = inav_correct(settings, samples)
    # What INAV can hold: the diagonal of magfit's matrix, scaled to a radius of 1024.
    expected = (samples - cal.offset) * np.diag(cal.matrix) * 1024 / cal.field_strength
    np.testing.assert_allclose(corrected, expected, atol=0.01 * 1024)  # integers: rounding of zero, gain, division
    np.testing.assert_allclose(np.median(np.linalg.norm(corrected, axis=1)), 1024, rtol=0.02)
    # The stated loss is the heading error of the integers INAV holds against magfit's full correction.
    zero = np.array([float(settings[f"magzero_{a}"]) for a in "xyz"])
    gain = np.array([float(settings[f"maggain_{a}"]) for a in "xyz"])
    assert _stated_loss(text) == pytest.approx(_level_heading_error(cal, np.diag(1024 / gain), zero), abs=0.05)


def _level_heading_error_of(
    cal: magfit.Calibration, correct: Callable[[NDArray[np.float64]], NDArray[np.float64]]
) -> float:
    """Worst heading error of ``correct(raw)``, sensor level, inclinations up to ±70° (a coarse grid)."""
    inc, head = np.meshgrid(np.radians(np.arange(-70, 71, 5.0)), np.radians(np.arange(0, 360, 1.0)))
    field = cal.field_strength * np.stack([np.cos(inc) * np.cos(head), np.cos(inc) * np.sin(head), np.sin(inc)], -1)
    field = field.reshape(-1, 3)
    seen = correct(field @ np.linalg.inv(cal.matrix).T + cal.offset)
    error = np.arctan2(seen[:, 1], seen[:, 0]) - np.arctan2(field[:, 1], field[:, 0])
    return float(np.degrees(np.max(np.abs((error + np.pi) % (2 * np.pi) - np.pi))))


@pytest.mark.parametrize("recording", ["apex5", "unc"])
def test_inav_states_the_loss_of_float_and_of_integer_builds(recording: str, real_data_dir: Path) -> None:
    # compass.c divides mag.magADC (compass.h: float since PR #9075, INAV 7.0; int32 before, so C's division
    # truncates toward zero): the integer builds lose up to about 0.2 deg more on a diag fit.
    samples = _apex5(real_data_dir) if recording == "apex5" else _unc(real_data_dir)
    cal = magfit.fit(samples, method="diag", allow_undetermined=True).with_unit("counts")
    text = export(cal, "inav")
    settings = parse_cli(text)
    zero = np.array([float(settings[f"magzero_{a}"]) for a in "xyz"])
    gain = np.array([float(settings[f"maggain_{a}"]) for a in "xyz"])
    in_float = _level_heading_error_of(cal, lambda raw: (raw - zero) * 1024 / gain)
    in_int32 = _level_heading_error_of(cal, lambda raw: np.trunc((raw - zero) * 1024 / gain))
    stated_float, stated_int32 = (float(v) for v in re.findall(r"up to ([\d.]+) deg (?:\(|with)", text))
    assert stated_float == pytest.approx(in_float, abs=0.03) and stated_int32 == pytest.approx(in_int32, abs=0.03)
    assert 0.1 < stated_int32 - stated_float < 0.3
    assert "INAV 7.0 and later, which compute in float" in text and "earlier INAV, which computes in int32" in text


def test_inav_loss_is_small_for_a_diag_fit_and_large_for_strong_off_diagonal_terms(real_data_dir: Path) -> None:
    samples = _unc(real_data_dir)
    full = export(magfit.fit(samples, method="ellipsoid").with_unit("counts"), "inav")
    diag = export(magfit.fit(samples, method="diag", allow_undetermined=True).with_unit("counts"), "inav")
    assert _stated_loss(diag) < 0.1  # a diag fit is what INAV holds: only the rounding is lost
    assert _stated_loss(full) > _stated_loss(diag)


def test_inav_and_betaflight_refuse_physical_units_and_int16_overflow() -> None:
    for name in ("inav", "betaflight"):
        with pytest.raises(
            ExportError, match=f"the {name} export writes the sensor's raw counts, but the samples are in uT"
        ):
            export(magfit.Calibration("test", np.zeros(3), np.eye(3), 50.0, unit="uT"), name)
        with pytest.raises(ExportError, match="int16"):
            export(magfit.Calibration("test", np.array([40000.0, 0, 0]), np.eye(3), 1000.0, unit="counts"), name)
    with pytest.raises(ExportError, match="maggain_x is an int16"):
        export(magfit.Calibration("test", np.zeros(3), np.eye(3), 40000.0), "inav")


# ---------------------------------------------------------------------- Betaflight


def test_betaflight_offset_matches_apply_and_the_flight_controllers_own_result(real_data_dir: Path) -> None:
    samples = _apex5(real_data_dir)
    cal = magfit.fit(samples, method="ellipsoid").with_unit("counts")
    text = export(cal, "betaflight")
    settings = parse_cli(text)
    zero = np.array([int(v) for v in settings["mag_calibration"].split(",")])  # settings.c: int16 array of 3
    np.testing.assert_array_equal(zero, np.rint(cal.offset))
    corrected = samples - zero  # compassUpdate: magADC = align(magADCRaw) - magZero (the samples are magADC)
    np.testing.assert_allclose(corrected, cal.apply(samples) @ np.linalg.inv(cal.matrix).T, atol=0.5 + 1e-9)
    # The README of the recordings: the flight controller's own hard-iron result for this file is
    # (957, 417, 502); magfit's agrees within 1 % of the field (1392 counts).
    np.testing.assert_allclose(zero, [957, 417, 502], atol=0.01 * cal.field_strength)
    loss = _level_heading_error(cal, np.eye(3), zero.astype(float))
    assert _stated_loss(text) == pytest.approx(loss, abs=0.05)


# ---------------------------------------------------------------------- RTIMULib


class RtimulibSettings:
    """RTIMUSettings::loadSettings on a file's text: defaults, then key=value lines (strcmp on the key)."""

    def __init__(self, text: str) -> None:
        self.cal_valid = False
        self.cal_min = np.zeros(3)
        self.cal_max = np.zeros(3)
        self.ellipsoid_valid = False
        self.offset = np.zeros(3)
        self.corr = np.eye(3)
        for line in text.splitlines(keepends=True):
            if line[0] in "# \n":  # RTIMULib skips lines starting with '#', ' ' or '\n'
                continue
            match = re.match(r"([^=]+)=(\S+)", line)  # sscanf("%[^=]=%s")
            assert match, line
            key, value = match.groups()
            number = float(np.float32(float(value))) if re.fullmatch(NUMBER, value) else 0.0  # sscanf %f
            if key == "CompassCalValid":
                self.cal_valid = value == "true"
            elif key == "compassCalEllipsoidValid":
                self.ellipsoid_valid = value == "true"
            elif m := re.fullmatch(r"CompassCal(Min|Max)([XYZ])", key):
                (self.cal_min if m.group(1) == "Min" else self.cal_max)["XYZ".index(m.group(2))] = number
            elif m := re.fullmatch(r"compassCalOffset([XYZ])", key):
                self.offset["XYZ".index(m.group(1))] = number
            elif m := re.fullmatch(r"compassCalCorr([123])([123])", key):
                self.corr[int(m.group(1)) - 1, int(m.group(2)) - 1] = number
            else:
                raise AssertionError(f"RTIMULib has no key {key!r}")

    def correct(self, compass_ut: NDArray[np.float64]) -> NDArray[np.float64]:
        """RTIMU::setCalibrationData then calibrateAverageCompass."""
        assert self.cal_valid  # without it RTIMULib applies neither stage
        delta = (self.cal_max - self.cal_min) / 2
        scale = np.max(delta) / delta
        centre = (self.cal_max + self.cal_min) / 2
        c = (compass_ut - centre) * scale
        if self.ellipsoid_valid:
            c = (c - self.offset) @ self.corr.T
        return c


def test_rtimulib_settings_applied_as_rtimulib_does(
    physical: tuple[magfit.Calibration, NDArray[np.float64], float],
) -> None:
    cal, samples, k = physical
    text = export(cal, "rtimulib")
    settings = RtimulibSettings(text)
    assert settings.ellipsoid_valid
    _close(settings.correct(k * samples), k * cal.apply(samples), k * samples, RTOL_FLOAT32)
    assert ("Cholesky root" in text) == (cal.details.get("root") == "cholesky")


# ---------------------------------------------------------------------- ROS


def test_ros_madgwick_bias_in_tesla_and_its_stated_loss(
    physical: tuple[magfit.Calibration, NDArray[np.float64], float],
) -> None:
    cal, samples, k = physical
    text = export(cal, "ros-madgwick")
    params = yaml.safe_load(text)["/**"]["ros__parameters"]
    assert set(params) == {"mag_bias_x", "mag_bias_y", "mag_bias_z"}
    bias = np.array([params[f"mag_bias_{a}"] for a in "xyz"])
    assert np.all(np.abs(bias) <= 10.0)  # the parameters' declared range
    tesla = 1e-6 * k * samples  # sensor_msgs/MagneticField is in tesla
    compensated = tesla - bias  # imuMagCallback: mag_compensated = mag_fld - mag_bias_
    np.testing.assert_allclose(compensated, 1e-6 * k * (samples - cal.offset), rtol=0, atol=1e-15)
    assert _stated_loss(text) == pytest.approx(_level_heading_error(cal, np.eye(3), cal.offset), abs=0.05)


def test_generic_yaml_reads_back_magfits_numbers(
    physical: tuple[magfit.Calibration, NDArray[np.float64], float],
) -> None:
    cal, samples, _ = physical
    data = yaml.safe_load(export(cal, "yaml"))["magnetometer_calibration"]
    assert data["convention"] == "corrected = matrix @ (raw - offset)" and data["unit"] == cal.unit
    offset, matrix = np.array(data["offset"]), np.array(data["matrix"])
    np.testing.assert_array_equal(offset, cal.offset)  # repr: the same doubles
    np.testing.assert_array_equal(matrix, cal.matrix)
    assert data["field_strength"] == cal.field_strength
    _close((samples - offset) @ matrix.T, cal.apply(samples), samples, 1e-14)
    odd = magfit.Calibration('it\'s "odd": #1', np.zeros(3), np.eye(3), 1.0)
    assert yaml.safe_load(export(odd, "yaml"))["magnetometer_calibration"]["method"] == 'it\'s "odd": #1'


def test_every_new_format_is_registered_with_its_unit() -> None:
    expected = {
        "adafruit": (".h", "uT"),
        "adafruit-json": (".json", "uT"),
        "inav": (".txt", "counts"),
        "betaflight": (".txt", "counts"),
        "rtimulib": (".ini", "uT"),
        "ros-madgwick": (".yaml", "T"),
        "yaml": (".yaml", None),
    }
    for name, (extension, unit) in expected.items():
        assert (FORMATS[name].extension, FORMATS[name].unit) == (extension, unit)
