"""Every compass of a vehicle in one file (issue 13): ArduPilot COMPASS_*, *2, *3 and PX4 CAL_MAG0..3.

The slot and the device id come from ``Calibration.sensor`` (filled by the pipeline from a flight log's
magnetometer) or from the explicit ``slot=`` / ``device_id=`` options, which win. Each compass's block is
applied with the firmware's formula (AP_Compass_Backend::correct_field, PX4 Magnetometer::Correct,
re-implemented in tests/test_export_vehicle.py) and must reproduce its own calibration.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray

import magfit
from magfit.errors import ExportError, OptionError
from magfit.export import FORMATS, SEVERAL, export, export_several
from magfit.facts import LogCompass
from test_export_vehicle import ardupilot_field, parse_ardupilot, parse_px4, px4_correct

RTOL_FLOAT32 = 2e-6


def _with_sensor(cal: magfit.Calibration, name: str, slot: int | None, device_id: int | None) -> magfit.Calibration:
    return dataclasses.replace(cal, sensor=LogCompass(name, slot, device_id))


@pytest.fixture(scope="module")
def three(real_data_dir: Path) -> tuple[list[magfit.Calibration], list[NDArray[np.float64]]]:
    """Three real recordings in physical units, as if they were a vehicle's three compasses (slots 2, 0, 1)."""
    fxos = np.loadtxt(real_data_dir / "fxos8700_magneto" / "mag-readings.txt")  # µT
    gauss = np.loadtxt(real_data_dir / "hamagure_gauss" / "data-set_1.csv", delimiter=",", skiprows=1)  # G
    cal_a = magfit.fit(fxos, method="ellipsoid").with_unit("uT")
    cal_b = magfit.fit(gauss, method="ellipsoid").with_unit("G")
    cal_c = magfit.fit(fxos, method="diag").with_unit("uT")
    cals = [
        _with_sensor(cal_a, "MAG/2", 2, 658953),
        _with_sensor(cal_b, "MAG/0", 0, 97539),
        _with_sensor(cal_c, "MAG/1", 1, None),
    ]
    return cals, [fxos, gauss, fxos]


def test_ardupilot_writes_each_compass_in_its_slot(
    three: tuple[list[magfit.Calibration], list[NDArray[np.float64]]],
) -> None:
    cals, samples = three
    # one unit per file: the gauss recording's calibration converted to µT first
    cals = [c if c.unit == "uT" else _to_ut(c) for c in cals]
    samples = [s if c.unit == "uT" else 100 * s for c, s in zip(three[0], samples, strict=True)]
    text = export_several(cals, "ardupilot")
    params = parse_ardupilot(text)
    for cal, raw in zip(cals, samples, strict=True):
        slot = cal.sensor.slot
        corrected = ardupilot_field(params, 10 * raw, slot)
        np.testing.assert_allclose(corrected, 10 * cal.apply(raw), rtol=0, atol=RTOL_FLOAT32 * 10 * np.abs(raw).max())
    assert "COMPASS_OFS3_X" in params and "COMPASS_SCALE2" in params and "COMPASS_OFS_X" in params
    # the device ids are named for the user to check, not loaded (ArduPilot sets COMPASS_DEV_ID* itself)
    assert "COMPASS_DEV_ID3 = 658953" in text and "COMPASS_DEV_ID = 97539" in text
    assert not any(name.startswith("COMPASS_DEV_ID") for name in params)
    assert text.index("COMPASS_OFS_X") < text.index("COMPASS_OFS2_X") < text.index("COMPASS_OFS3_X")


def _to_ut(cal: magfit.Calibration) -> magfit.Calibration:
    return dataclasses.replace(cal, offset=100 * cal.offset, field_strength=100 * cal.field_strength, unit="uT")


def test_px4_writes_each_slot_with_its_device_id(
    three: tuple[list[magfit.Calibration], list[NDArray[np.float64]]],
) -> None:
    cals, samples = three
    text = export_several(cals, "px4", system_id=3)
    params = parse_px4(text.replace("\n3\t", "\n1\t"))
    assert params["CAL_MAG2_ID"] == 658953 and params["CAL_MAG0_ID"] == 97539 and "CAL_MAG1_ID" not in params
    for cal, raw in zip(cals, samples, strict=True):
        k = 0.01 if cal.unit == "uT" else 1.0
        slot = cal.sensor.slot
        np.testing.assert_allclose(
            px4_correct(params, k * raw, slot), k * cal.apply(raw), rtol=0, atol=RTOL_FLOAT32 * k * np.abs(raw).max()
        )
    assert "CAL_MAG1_* only to the sensor whose id is CAL_MAG1_ID" in text


def test_explicit_slot_and_device_id_win(three: tuple[list[magfit.Calibration], list[NDArray[np.float64]]]) -> None:
    cal = three[0][0]  # details: slot 2, device 658953
    params = parse_ardupilot(export(cal, "ardupilot"))
    assert "COMPASS_OFS3_X" in params
    params = parse_ardupilot(export(cal, "ardupilot", slot=1))
    assert "COMPASS_OFS2_X" in params and "COMPASS_OFS3_X" not in params
    px4 = parse_px4(export(cal, "px4", slot=3, device_id=1234))
    assert px4["CAL_MAG3_ID"] == 1234 and "CAL_MAG3_XOFF" in px4
    plain = dataclasses.replace(cal, sensor=None)
    assert "COMPASS_OFS_X" in parse_ardupilot(export(plain, "ardupilot"))  # no sensor known: the first slot


def test_refusals(three: tuple[list[magfit.Calibration], list[NDArray[np.float64]]]) -> None:
    cals = three[0]
    with pytest.raises(ExportError, match="two calibrations are for ardupilot compass slot 2"):
        export_several([cals[0], cals[0]], "ardupilot")
    with pytest.raises(ExportError, match="two calibrations are for PX4 slot CAL_MAG0"):
        export_several([cals[1], cals[1]], "px4")
    for name in FORMATS:
        if name not in SEVERAL:
            with pytest.raises(ExportError, match=f"the {name} export holds one compass; export each"):
                export_several(cals, name)
    with pytest.raises(OptionError, match="slot must be the ardupilot compass slot, an integer from 0 to 2"):
        export(cals[1], "ardupilot", slot=3)
    with pytest.raises(OptionError, match="from 0 to 3"):
        export(cals[1], "px4", slot=4)
    with pytest.raises(OptionError, match="device_id must be"):
        export(cals[1], "px4", device_id=-5)
    with pytest.raises(OptionError, match="the c export takes no slot; slot applies to: ardupilot, px4"):
        export(cals[1], "c", slot=0)
    with pytest.raises(OptionError, match="one entry per calibration"):
        export_several(cals, "px4", slots=[0, 1])
    slot3 = _with_sensor(cals[1], "MAG/3", 3, None)
    with pytest.raises(ExportError, match="ardupilot calibrates 3 compasses"):
        export(slot3, "ardupilot")
    export(slot3, "px4")  # PX4 has four slots


def test_json_holds_several_as_a_list(three: tuple[list[magfit.Calibration], list[NDArray[np.float64]]]) -> None:
    cals = three[0]
    data = json.loads(export_several(cals, "json"))
    assert [magfit.Calibration.from_dict(item) for item in data] == cals
