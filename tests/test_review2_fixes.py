"""The fixes of the second review's defects: fleet's combined rows per compass, align's columns found by name and
the options its advice names (each against the simulated truth where there is one)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import magfit
from magfit.fleet import FleetRow, fleet
from magfit.report.fleet import fleet_report_html
from test_sources_dataflash import COMPASSES, write_new_style


def _matrix(row: FleetRow | dict[str, object]) -> np.ndarray:
    get = row.get if isinstance(row, dict) else lambda name: getattr(row, name)
    return np.array([[float(get(f"matrix_{a}{b}")) for b in "xyz"] for a in "xyz"])  # type: ignore[arg-type]


def _offset(row: FleetRow | dict[str, object]) -> np.ndarray:
    get = row.get if isinstance(row, dict) else lambda name: getattr(row, name)
    return np.array([float(get(f"offset_{a}")) for a in "xyz"])  # type: ignore[arg-type]


def _assert_is_truth(row: FleetRow | dict[str, object], truth: magfit.Calibration) -> None:
    # 0.3 % noise and int16 truncation on 1500 samples a flight: the ellipsoid within 1 % of its largest entry,
    # the offset within 1 % of the field (the two compasses' offsets are 200-350 mG apart: a mix-up is far out).
    fitted = _matrix(row)
    ellipsoid = fitted.T @ fitted / float(row["field_strength"] if isinstance(row, dict) else row.field_strength) ** 2
    scale = float(np.max(np.abs(truth.ellipsoid_matrix)))
    np.testing.assert_allclose(ellipsoid, truth.ellipsoid_matrix, atol=0.01 * scale)
    np.testing.assert_allclose(_offset(row), truth.offset, atol=0.01 * truth.field_strength)


@pytest.fixture(scope="module")
def two_compass_vehicle(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[int, magfit.Calibration]]:
    """One vehicle, two logs of two compasses; the second log lists them in the other order (MAG/0 is the
    first log's MAG/1): a compass is its device id, not its slot. Returns the folder and each device's truth."""
    folder = tmp_path_factory.mktemp("fleet_compasses") / "copter"
    folder.mkdir()
    simulations = write_new_style(folder / "a.bin")
    write_new_style(folder / "b.bin", swap_priority=True)
    return folder, {int(c["dev_id"]): simulations[k].truth for k, c in enumerate(COMPASSES)}


def _devices(rows: list[dict[str, str]], kind: str) -> list[int]:
    return sorted(int(row["device_id"]) for row in rows if row["kind"] == kind)


@pytest.mark.parametrize("suffix", [".csv", ".jsonl", ".parquet"])
def test_fleet_combines_each_compass_into_its_own_row_with_its_own_calibration(
    two_compass_vehicle: tuple[Path, dict[int, magfit.Calibration]], tmp_path: Path, suffix: str
) -> None:
    folder, truths = two_compass_vehicle
    table = tmp_path / f"fleet{suffix}"
    result = fleet([folder], table, method="ellipsoid", workers=1, resume=False)
    combined = result.combined()
    assert sorted(row.device_id for row in combined) == sorted(truths)  # type: ignore[type-var]
    for row in combined:
        assert row.flights == 2 and row.verdict in ("supported", "weak"), row
        _assert_is_truth(row, truths[int(row.device_id)])  # type: ignore[arg-type]
    # The table holds the same rows: each compass's combined calibration under its own device id.
    if suffix == ".csv":
        rows = list(csv.DictReader(table.open()))
    elif suffix == ".jsonl":
        rows = [json.loads(line) for line in table.read_text().splitlines()]
    else:
        rows = pd.read_parquet(table).to_dict("records")
    assert _devices(rows, "combined") == sorted(truths)
    assert _devices(rows, "flight") == sorted([*truths, *truths])
    for row in rows:
        if row["kind"] == "combined":
            _assert_is_truth(row, truths[int(row["device_id"])])


def test_a_resumed_fleet_run_combines_each_compass_as_the_first_did(
    two_compass_vehicle: tuple[Path, dict[int, magfit.Calibration]], tmp_path: Path
) -> None:
    folder, truths = two_compass_vehicle
    table = tmp_path / "fleet.csv"
    first = fleet([folder], table, method="ellipsoid", workers=1, resume=False)
    again = fleet([folder], table, method="ellipsoid", workers=1)
    assert again.skipped == 2  # both recordings from the journal, their compasses' statistics with them
    assert [(r.sensor, r.device_id) for r in again.combined()] == [(r.sensor, r.device_id) for r in first.combined()]
    assert sorted(row.device_id for row in again.combined()) == sorted(truths)  # type: ignore[type-var]
    for row in again.combined():
        _assert_is_truth(row, truths[int(row.device_id)])  # type: ignore[arg-type]


def test_the_fleet_report_shows_each_compass_combined_with_its_device_id(
    two_compass_vehicle: tuple[Path, dict[int, magfit.Calibration]],
) -> None:
    folder, truths = two_compass_vehicle
    result = fleet([folder], method="ellipsoid", workers=1)
    html = fleet_report_html(result)
    combined = html.split("<h2>Combined calibrations</h2>")[1].split("</table>")[0]
    for device in truths:
        assert combined.count(f"<td>{device}</td>") == 1, device

