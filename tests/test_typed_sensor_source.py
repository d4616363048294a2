"""Where a calibration's samples came from, typed: ``Calibration.sensor`` (a log's compass) and
``Calibration.source`` (the file and its columns), read by the exports, ``magfit apply`` and the fleet.

The files under tests/data/details_v2 were written by magfit at commit 392e4f6, when the two were still
``details["sensor"]`` and ``details["source"]`` (tests/data/details_v2/README): they must load with the typed
fields filled, and give the same exports and the same ``apply`` as a calibration written today."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import magfit
import test_sources_motion as motion_log
from magfit.cli import cli
from magfit.cli.apply import fitted_sensor, remembered_columns
from magfit.errors import DataFileError, ExportError, SampleError
from magfit.export import export
from magfit.export._common import with_applied_rotation
from magfit.facts import LogCompass, SampleSource
from magfit.io.layout import sniff
from test_sources_dataflash import COMPASSES, write_new_style

OLD = Path(__file__).parent / "data" / "details_v2"
#: The simulation tests/data/details_v2/samples_csv.json was fitted on (its README).
TRUE_OFFSET = np.array([12.0, -7.0, 3.0])
TRUE_SOFT = np.array([[1.1, 0.05, 0.0], [0.05, 0.95, 0.02], [0.0, 0.02, 1.02]])


def _old(name: str) -> tuple[magfit.Calibration, dict]:
    text = (OLD / f"{name}.json").read_text()
    return magfit.Calibration.from_json(text), json.loads(text)


def _tumble_csv(path: Path) -> np.ndarray:
    """The samples file samples_csv.json was fitted on, written again (same simulation, same layout)."""
    simulation = magfit.simulate(
        2000, hard_iron=TRUE_OFFSET, soft_iron=TRUE_SOFT, field_strength=48.0, noise=0.4, seed=3
    )
    with path.open("w") as file:
        file.write("time,mag_x,mag_y,mag_z,temp\n")
        for i, row in enumerate(simulation.samples):
            file.write(f"{i * 0.01:.2f},{row[0]:.5f},{row[1]:.5f},{row[2]:.5f},25.0\n")
    return np.loadtxt(path, delimiter=",", skiprows=1)


@pytest.mark.parametrize("name", ["samples_csv", "dataflash_mag1", "dataflash_vector_rotated", "tlog_residual"])
def test_an_older_file_with_details_sensor_and_source_loads_them_as_typed_fields(name: str) -> None:
    calibration, raw = _old(name)
    assert raw["schema_version"] == 2 and "source" in raw["details"] and "source" not in raw
    assert "sensor" not in calibration.details and "source" not in calibration.details
    source = raw["details"]["source"]
    assert calibration.source is not None
    assert (calibration.source.file, calibration.source.unit) == (source["file"], source["unit"])
    if "sensor" in raw["details"]:
        sensor = raw["details"]["sensor"]
        assert calibration.sensor is not None
        assert (calibration.sensor.id, calibration.sensor.slot, calibration.sensor.device_id) == (
            sensor["id"], sensor["slot"], sensor["device_id"]
        )  # fmt: skip
        assert calibration.sensor.id == source["sensor"] and calibration.sensor.device_id == source["device_id"]
        assert calibration.sensor.calibration_in_use == sensor.get("calibration_in_use")
    else:
        assert calibration.sensor is None
        assert calibration.source.columns == tuple(source["columns"])
        assert calibration.source.column_indices == tuple(source["column_indices"])
        assert (calibration.source.header, calibration.source.n_columns) == (source["header"], source["n_columns"])
    # written again, the two are top-level facts, and read back equal
    document = json.loads(calibration.to_json())
    assert document["schema_version"] == 2 and "source" in document and "source" not in document["details"]
    assert magfit.Calibration.from_json(calibration.to_json()) == calibration
    assert calibration.to_json() == magfit.Calibration.from_json(calibration.to_json()).to_json()


def test_the_old_samples_file_calibration_is_todays_and_apply_reads_its_columns(tmp_path: Path) -> None:
    old, _ = _old("samples_csv")
    path = tmp_path / "tumble.csv"
    table = _tumble_csv(path)
    today = magfit.calibrate_file(path, "ellipsoid", unit="uT").calibration
    assert today.source == old.source == SampleSource(
        "tumble.csv", "uT", ("mag_x", "mag_y", "mag_z"), (1, 2, 3), header=True, n_columns=5
    )
    np.testing.assert_allclose(old.offset, TRUE_OFFSET, atol=0.2)  # the simulation's truth
    assert remembered_columns(old, sniff(path)) == ["mag_x", "mag_y", "mag_z"]
    output = tmp_path / "out.csv"
    result = CliRunner().invoke(cli, ["apply", str(OLD / "samples_csv.json"), str(path), "-o", str(output)])
    assert result.exit_code == 0, result.output
    written = np.loadtxt(output, delimiter=",", skiprows=1)
    np.testing.assert_allclose(written[:, 1:4], old.apply(table[:, 1:4]), rtol=1e-9, atol=1e-6)
    np.testing.assert_array_equal(written[:, [0, 4]], table[:, [0, 4]])
    # ground truth: on the sphere of the simulated field strength, spread by the simulated noise (0.4)
    norms = np.linalg.norm(written[:, 1:4], axis=1)
    assert np.mean(norms) == pytest.approx(48.0 * np.linalg.det(TRUE_SOFT) ** (1 / 3), rel=0.01)
    assert np.std(norms) < 0.6


def test_a_headerless_file_is_applied_by_position_only_with_as_many_columns(tmp_path: Path) -> None:
    calibration = magfit.Calibration.identity(48.0)
    calibration = dataclasses.replace(
        calibration, source=SampleSource("m.txt", None, ("column 2", "column 3", "column 4"), (1, 2, 3), False, 4)
    )
    four, five = tmp_path / "four.txt", tmp_path / "five.txt"
    np.savetxt(four, np.ones((20, 4)))
    np.savetxt(five, np.ones((20, 5)))
    assert remembered_columns(calibration, sniff(four)) == [1, 2, 3]
    assert remembered_columns(calibration, sniff(five)) is None  # a position means nothing in another layout


def test_the_old_log_calibration_names_its_compass_as_today(tmp_path: Path) -> None:
    old, _ = _old("dataflash_mag1")
    log = tmp_path / "flight.bin"
    write_new_style(log)
    today = magfit.calibrate_file(log, "ellipsoid", sensor="MAG/1").calibration
    assert today.sensor == old.sensor == LogCompass("MAG/1", 1, COMPASSES[1]["dev_id"])
    assert today.source == old.source == SampleSource("flight.bin", "mG")
    assert fitted_sensor(old) == "MAG/1"
    # an export writes it for its slot and names its device id, the same from the old file as from today's
    text = export(old, "ardupilot")
    assert "COMPASS_OFS2_X" in text and "COMPASS_OFS_X" not in text
    assert f"COMPASS_DEV_ID2 = {COMPASSES[1]['dev_id']}" in text
    for format in ("ardupilot", "px4"):
        ids = [line for line in export(old, format).splitlines() if "DEV_ID" in line or "_ID\t" in line]
        assert ids and ids == [line for line in export(today, format).splitlines() if line in ids]


def test_the_rotation_applied_before_logging_reaches_the_export_from_an_old_file() -> None:
    old, raw = _old("dataflash_vector_rotated")
    r0 = motion_log.standard_rotations("ardupilot")[motion_log.ORIENT].matrix
    assert old.sensor is not None and old.sensor.applied_rotation is not None
    np.testing.assert_allclose(np.array(old.sensor.applied_rotation), r0, atol=1e-12)
    np.testing.assert_allclose(old.offset, motion_log.HARD, atol=3.0)  # the simulated truth (body frame)
    # the export includes the rotation: the same text as when it is given explicitly
    bare = dataclasses.replace(old, sensor=dataclasses.replace(old.sensor, applied_rotation=None))
    assert export(old, "ardupilot") == export(bare, "ardupilot", applied_rotation=r0)
    assert "mounting rotation of" in export(old, "ardupilot")
    # re-expressed for the sensor's readings, it keeps its facts and no longer carries the rotation: idempotent
    turned = with_applied_rotation(old, None)
    assert turned.sensor == dataclasses.replace(old.sensor, applied_rotation=None) and turned.support == old.support
    assert with_applied_rotation(turned, None) == turned
    sensor_raw = np.random.default_rng(0).normal(size=(50, 3)) * 400
    np.testing.assert_allclose(turned.apply(sensor_raw), old.apply(sensor_raw @ r0.T), atol=1e-9)
    assert raw["details"]["sensor"]["applied_rotation"] == [list(row) for row in old.sensor.applied_rotation]


def test_a_residual_on_the_firmwares_calibration_is_refused_by_the_firmware_formats_from_an_old_file() -> None:
    old, _ = _old("tlog_residual")
    assert old.sensor is not None and old.sensor.calibration_in_use
    with pytest.raises(ExportError) as refused:
        export(old, "ardupilot")
    assert "already carry the firmware's calibration" in str(refused.value)
    kept = magfit.Calibration.from_json(export(old, "json"))
    assert kept.sensor == old.sensor


def test_a_version_1_source_naming_the_log_compass_gives_the_sensor() -> None:
    _, raw = _old("dataflash_mag1")
    raw = {**raw, "schema_version": 1, "details": dict(raw["details"])}
    for name in ("support", "model", "options", "solver", "known_field", "rejected", "auto", "vector", "gyro"):
        if name in raw:
            raw["details"][name] = raw.pop(name)
    del raw["details"]["sensor"]
    calibration = magfit.Calibration.from_dict(raw)
    assert calibration.sensor == LogCompass("MAG/1", None, COMPASSES[1]["dev_id"])
    assert calibration.source == SampleSource("flight.bin", "mG")


@pytest.mark.parametrize(
    ("where", "value"),
    [
        ("sensor", {"id": 5}),
        ("sensor", {"id": "MAG/0", "slot": "one"}),
        ("sensor", {"id": "MAG/0", "applied_rotation": [[1, 0], [0, 1]]}),
        ("source", {"file": "a.csv", "column_indices": [1, -2, 3]}),
        ("source", {"file": "a.csv", "header": "yes"}),
        ("source", {"unit": "uT"}),
    ],
)
def test_a_malformed_sensor_or_source_is_named_in_one_line(where: str, value: dict) -> None:
    _, raw = _old("dataflash_mag1")
    for top_level in (True, False):
        document = json.loads(json.dumps(raw))
        if top_level:
            document[where] = value
        else:
            document["details"][where] = value
        if not top_level and "id" not in value and "file" not in value:
            # not a record at all (no id, no file): kept as a free-form extra, as any other details key
            assert magfit.Calibration.from_dict(document).details[where] == value
            continue
        with pytest.raises(DataFileError) as error:
            magfit.Calibration.from_dict(document)
        message = str(error.value)
        assert "\n" not in message and "malformed" in message
        if top_level:
            assert repr(where) in message


def test_the_typed_fields_are_frozen_checked_and_round_trip() -> None:
    rotation = ((0.0, 1.0, 0.0), (-1.0, 0.0, 0.0), (0.0, 0.0, 1.0))
    calibration = dataclasses.replace(
        magfit.Calibration.identity(50.0, unit="uT"),
        sensor=LogCompass("MAG/2", 2, 658953, rotation, None),
        source=SampleSource("f.csv", "uT", ("a", "b", "c"), (0, 1, 2), True, 3, ("reference: ATT",)),
    )
    again = magfit.Calibration.from_json(calibration.to_json())
    assert again == calibration and again.sensor == calibration.sensor and again.source == calibration.source
    with pytest.raises(dataclasses.FrozenInstanceError):
        calibration.sensor.slot = 0  # type: ignore[misc, union-attr]
    with pytest.raises(SampleError, match="Calibration.sensor must be a LogCompass"):
        dataclasses.replace(calibration, sensor={"id": "MAG/0"})  # type: ignore[arg-type]
    with pytest.raises(SampleError, match="Calibration.source must be a SampleSource"):
        dataclasses.replace(calibration, source="f.csv")  # type: ignore[arg-type]
    # the fields differ: the calibrations differ
    assert dataclasses.replace(calibration, sensor=LogCompass("MAG/1", 1)) != calibration
