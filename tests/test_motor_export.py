"""The motors' field in the exports, checked against each firmware's correction re-implemented from its source.

- ArduPilot ``AP_Compass_Backend::correct_field``: ``mag += OFS; mag *= SCALE; mag = DIA/ODI · mag;
  mag += MOT · x`` (x: current in A with COMPASS_MOTCT 2, throttle 0-1 with 1), milligauss, body frame.
- PX4 ``calibration::Magnetometer::Correct``: ``R · (S · ((raw + power · COMP) − OFF))``, gauss, with
  ``power = battery_status.current_a · 0.001`` (CAL_MAG_COMP_TYP 2) or the thrust (1).
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from magfit import Calibration
from magfit.errors import ExportError
from magfit.export import export, export_several
from magfit.motorterm import MotorTerm


def parse_ardupilot(text: str) -> dict[str, float]:
    return {
        name: float(value)
        for name, value in (line.split(",") for line in text.splitlines() if line.strip() and not line.startswith("#"))
    }


def ardupilot_correct(p: dict[str, float], raw_mg: np.ndarray, x: np.ndarray, n: str = "") -> np.ndarray:
    """AP_Compass_Backend::correct_field (ArduPilot 4.x) for compass suffix ``n``, sample by sample."""
    ofs = np.array([p[f"COMPASS_OFS{n}_{a}"] for a in "XYZ"])
    dia = [p[f"COMPASS_DIA{n}_{a}"] for a in "XYZ"]
    odi = [p[f"COMPASS_ODI{n}_{a}"] for a in "XYZ"]
    mat = np.array([[dia[0], odi[0], odi[1]], [odi[0], dia[1], odi[2]], [odi[1], odi[2], dia[2]]])
    mot = np.array([p.get(f"COMPASS_MOT{n}_{a}", 0.0) for a in "XYZ"])
    motct = p.get("COMPASS_MOTCT", 0.0)
    scale = p[f"COMPASS_SCALE{n}"]
    out = np.empty_like(raw_mg)
    for i, sample in enumerate(raw_mg):
        mag = sample + ofs
        if 0.85 <= scale <= 1.4:
            mag = mag * scale
        mag = mat @ mag
        if motct != 0:
            mag = mag + mot * x[i]  # after the matrix: "we apply the motor offsets after ... the eliptical correction"
        out[i] = mag
    return out


def parse_px4(text: str) -> dict[str, float]:
    params = {}
    for line in text.splitlines():
        if line.strip() and not line.startswith("#"):
            _, _, name, value, kind = line.split("\t")
            assert kind == ("6" if name in ("CAL_MAG_COMP_TYP",) or name.endswith("_ID") else "9")
            params[name] = float(value)
    return params


def px4_correct(p: dict[str, float], raw_g: np.ndarray, power: np.ndarray, slot: int = 0) -> np.ndarray:
    """Magnetometer::Correct with R = identity: S * ((raw + power * COMP) - OFF)."""
    m = f"CAL_MAG{slot}_"
    off = np.array([p[f"{m}{a}OFF"] for a in "XYZ"])
    comp = np.array([p.get(f"{m}{a}COMP", 0.0) for a in "XYZ"])
    sc = [p[f"{m}{a}SCALE"] for a in "XYZ"]
    od = [p[f"{m}{a}ODIAG"] for a in "XYZ"]
    s = np.array([[sc[0], od[0], od[1]], [od[0], sc[1], od[2]], [od[1], od[2], sc[2]]])
    return np.array([s @ ((raw + pw * comp) - off) for raw, pw in zip(raw_g, power, strict=True)])


def _calibration(regressor: str = "current", unit: str = "uT", slot: int = 0) -> Calibration:
    soft = np.array([[1.05, 0.03, -0.02], [0.03, 0.97, 0.01], [-0.02, 0.01, 1.0]])
    soft /= np.cbrt(np.linalg.det(soft))
    per = 0.35 if regressor == "current" else 14.0  # µT per A, or per full throttle
    term = MotorTerm(
        regressor, per * np.array([0.3, -0.8, 0.52]), lag_s=0.02, full_scale=45.0 if regressor == "current" else 1.0
    )
    return Calibration(
        "ellipsoid", [12.0, -7.5, 20.0], soft, 50.0, unit=unit, motor=term,
        details={"sensor": {"id": "MAG", "slot": slot, "device_id": None}},
    )  # fmt: skip


def _raw(calibration: Calibration, n: int = 50, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    directions = rng.normal(size=(n, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    assert calibration.motor is not None
    x = rng.uniform(0, calibration.motor.full_scale, n)
    raw = np.linalg.solve(calibration.matrix, (calibration.field_strength * directions).T).T + calibration.offset
    return raw + calibration.motor.field(x), x


@pytest.mark.parametrize("regressor", ["current", "throttle"])
def test_ardupilot_mot_reproduces_the_calibration(regressor: str) -> None:
    calibration = _calibration(regressor)
    raw, x = _raw(calibration)
    params = parse_ardupilot(export(calibration, "ardupilot"))
    assert params["COMPASS_MOTCT"] == (2 if regressor == "current" else 1)
    firmware = ardupilot_correct(params, 10.0 * raw, x)  # µT -> mG
    np.testing.assert_allclose(firmware, 10.0 * calibration.apply(raw, regressor=x), rtol=0, atol=1e-3 * 500)


def test_ardupilot_mot_with_a_scale_factor() -> None:
    calibration = _calibration()
    raw, x = _raw(calibration)
    params = parse_ardupilot(export(calibration, "ardupilot", expected_field=55.0))
    scale = params["COMPASS_SCALE"]
    assert 1.05 < scale < 1.15
    firmware = ardupilot_correct(params, 10.0 * raw, x)
    np.testing.assert_allclose(firmware, 10.0 * scale * calibration.apply(raw, regressor=x), rtol=0, atol=0.5)


@pytest.mark.parametrize("regressor", ["current", "throttle"])
def test_px4_comp_reproduces_the_calibration(regressor: str) -> None:
    calibration = _calibration(regressor)
    raw, x = _raw(calibration)
    params = parse_px4(export(calibration, "px4"))
    assert params["CAL_MAG_COMP_TYP"] == (2 if regressor == "current" else 1)
    power = x * 0.001 if regressor == "current" else x  # VehicleMagnetometer: current_a * 0.001 (kA), or thrust
    firmware = px4_correct(params, 0.01 * raw, power)  # µT -> G
    np.testing.assert_allclose(firmware, 0.01 * calibration.apply(raw, regressor=x), rtol=0, atol=1e-6 * 50)


def test_one_motct_for_two_compasses_prefers_the_current_and_zeroes_the_other() -> None:
    first, second = _calibration("throttle", slot=0), _calibration("current", slot=1)
    text = export_several([first, second], "ardupilot")
    params = parse_ardupilot(text)
    assert params["COMPASS_MOTCT"] == 2
    assert [params[f"COMPASS_MOT_{a}"] for a in "XYZ"] == [0.0, 0.0, 0.0]  # the throttle compass's term dropped
    assert "WARNING: this compass's motors' field follows the throttle" in text
    raw, x = _raw(second)
    firmware = ardupilot_correct(params, 10.0 * raw, x, n="2")
    np.testing.assert_allclose(firmware, 10.0 * second.apply(raw, regressor=x), rtol=0, atol=0.5)
    px4 = export_several([first, second], "px4")
    lines = [line for line in px4.splitlines() if "\tCAL_MAG_COMP_TYP\t" in line and not line.startswith("#")]
    assert len(lines) == 1 and parse_px4(px4)["CAL_MAG_COMP_TYP"] == 2
    params = parse_px4(px4)
    assert [params[f"CAL_MAG0_{a}COMP"] for a in "XYZ"] == [0.0, 0.0, 0.0]
    firmware = px4_correct(params, 0.01 * raw, x * 0.001, slot=1)
    np.testing.assert_allclose(firmware, 0.01 * second.apply(raw, regressor=x), rtol=0, atol=1e-5)


@pytest.mark.parametrize("format", ["fusion", "magcal", "inav", "betaflight", "rtimulib", "ros-madgwick", "yaml"])
def test_formats_without_a_place_refuse_with_the_heading_cost(format: str) -> None:
    with pytest.raises(ExportError) as error:
        export(_calibration(), format)
    assert error.value.codes == ("motor_not_exportable",)
    assert "heading error of up to" in str(error.value)


def test_json_holds_the_term_losslessly() -> None:
    calibration = _calibration()
    assert Calibration.from_json(export(calibration, "json")) == calibration


@pytest.mark.external
@pytest.mark.skipif(shutil.which("cc") is None, reason="no C compiler")
def test_c_header_applies_the_term(tmp_path: Path) -> None:
    calibration = _calibration()
    raw, x = _raw(calibration, n=5)
    (tmp_path / "magfit.h").write_text(export(calibration, "c"))
    rows = "\n".join(
        f"    {{ float r[3] = {{{r[0]:.9g}f, {r[1]:.9g}f, {r[2]:.9g}f}}, c[3]; magfit_correct_motor(r, {c:.9g}f, c);"
        ' printf("%.9g %.9g %.9g\\n", c[0], c[1], c[2]); }'
        for r, c in zip(raw, x, strict=True)
    )
    (tmp_path / "main.c").write_text(
        f'#include <stdio.h>\n#include "magfit.h"\nint main(void) {{\n{rows}\n    return 0;\n}}\n'
    )
    subprocess.run(["cc", "-std=c99", "-o", str(tmp_path / "main"), str(tmp_path / "main.c")], check=True, timeout=60)
    out = subprocess.run([str(tmp_path / "main")], capture_output=True, text=True, check=True, timeout=60).stdout
    got = np.array([[float(v) for v in line.split()] for line in out.splitlines()])
    np.testing.assert_allclose(got, calibration.apply(raw, regressor=x), rtol=0, atol=1e-3)


def test_c_header_without_a_term_is_unchanged() -> None:
    plain = Calibration("ellipsoid", [1.0, 2.0, 3.0], np.eye(3), 50.0, unit="uT")
    assert "magfit_motor" not in export(plain, "c")
