"""The fixes of the second review's defects: fleet's combined rows per compass, align's columns found by name and
the options its advice names (each against the simulated truth where there is one)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import click
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


# ---------------------------------------------------------------------------------------------- align


@pytest.fixture(scope="module")
def car(tmp_path_factory: pytest.TempPathFactory) -> tuple[object, Path, Path]:
    """A car's recording (simulated; mount a few degrees off the body axes): its truth, the file with accel,
    attitude and reference N/E/D columns, and the same file without the reference columns."""
    from vehicle_recordings import save_columns, vehicle_recording

    sim, columns = vehicle_recording("car", 1)
    folder = tmp_path_factory.mktemp("align_car")
    save_columns(folder / "car.csv", columns)
    save_columns(folder / "car_no_reference.csv", {k: v for k, v in columns.items() if not k.startswith("ref_")})
    return sim, folder / "car.csv", folder / "car_no_reference.csv"


def _rotation(output: str) -> tuple[np.ndarray, float]:
    """The rotation ``magfit align`` prints (body = rotation @ sensor) and its one-sigma (RMS angle, degrees)."""
    lines = output.splitlines()
    first = next(i for i, line in enumerate(lines) if line.startswith("rotation "))
    rows = [line[line.index("(") + 1 : line.index(")")] for line in lines[first : first + 3]]
    sigma = next(line for line in lines if line.startswith("roll pitch yaw")).split("±")[1].split("°")[0]
    return np.array([[float(value) for value in row.split(",")] for row in rows]), float(sigma)


def test_align_finds_the_mount_from_the_attitude_and_reference_it_finds_by_name(
    car: tuple[object, Path, Path],
) -> None:
    from click.testing import CliRunner

    from magfit.cli import cli

    sim, path, _ = car
    found = CliRunner().invoke(cli, ["align", str(path), "--unit", "uT"])
    assert found.exit_code == 0, found.output
    told = CliRunner().invoke(
        cli, ["align", str(path), "--unit", "uT", "--attitude", "roll,pitch,yaw", "--reference", "ref_n,ref_e,ref_d"]
    )
    assert told.exit_code == 0, told.output
    rotation, sigma = _rotation(found.output)
    np.testing.assert_allclose(rotation, _rotation(told.output)[0], atol=1e-12)  # the columns found = those named
    # Ground truth: the simulated mount (body = mounting @ sensor), within three of the one-sigma stated.
    mounting = np.asarray(sim.mounting)  # type: ignore[attr-defined]
    error = np.degrees(np.arccos(np.clip((np.trace(rotation.T @ mounting) - 1) / 2, -1.0, 1.0)))
    assert error <= 3 * sigma, (error, sigma)
    assert np.degrees(np.arccos((np.trace(mounting) - 1) / 2)) > 3 * error  # the mount found, not the identity


def _foreign_flags(stderr: str) -> list[str]:
    """The options a message names that the command they belong to lacks: ``magfit align``'s own words, or
    those after a ``magfit COMMAND FILE`` (up to the next bracket or semicolon) that COMMAND lacks."""
    import re

    from magfit.cli import cli
    from magfit.cli._advice import flags_of

    def flags(name: str) -> frozenset[str]:
        command = cli.get_command(click.Context(cli), name)
        assert command is not None, name
        return flags_of(command)

    foreign = []
    for line in stderr.splitlines():
        pieces = re.split(r"(magfit [a-z]+ )", line)  # [align's words, 'magfit X ', its words, ...]
        owners = ["align"] + [piece.split()[1] for piece in pieces[1::2]]
        for owner, words in zip(owners, pieces[::2], strict=True):
            said, rest = re.split(r"[);]", words, maxsplit=1) if owner != "align" else (words, "")
            for text, command in ((said, owner), (rest, "align")):
                foreign += [f"{command}: {m.group()}" for m in re.finditer(r"(?<![\w-])--[a-z][a-z-]*", text)
                            if m.group() not in flags(command)]  # fmt: skip
    return foreign


def test_align_refusal_names_its_own_options_and_other_commands_in_full(car: tuple[object, Path, Path]) -> None:
    from click.testing import CliRunner

    from magfit.cli import cli

    _, full, path = car
    # No reference columns: the gravity path, whose starting calibration a car's level turns do not determine.
    result = CliRunner().invoke(cli, ["align", str(path), "--unit", "uT"])
    assert result.exit_code == 1, result.output
    assert _foreign_flags(result.stderr) == [], result.stderr
    assert f"magfit calibrate {path} --method vector" in result.stderr  # the other command, with the file
    # --accel-columns chooses the gravity path even where the vector fit's columns are found: the same refusal.
    chosen = CliRunner().invoke(cli, ["align", str(full), "--unit", "uT", "--accel-columns", "ax,ay,az"])
    assert chosen.exit_code == 1, chosen.output
    assert _foreign_flags(chosen.stderr) == [], chosen.stderr
    assert f"magfit calibrate {full} --method vector" in chosen.stderr


def test_align_says_the_call_that_would_run_as_align(tmp_path: Path) -> None:
    from click.testing import CliRunner

    from magfit.cli import cli
    from vehicle_recordings import save_columns, vehicle_recording

    _, columns = vehicle_recording("car", 1)
    path = tmp_path / "attitude_only.csv"  # the attitude by name, no accelerometer, no reference field
    save_columns(path, {k: v for k, v in columns.items() if not k.startswith(("ref_", "a"))})
    result = CliRunner().invoke(cli, ["align", str(path), "--unit", "uT"])
    assert result.exit_code == 2, result.output
    assert f"magfit align {path} --unit uT --reference N,E,D" in result.stderr
    assert _foreign_flags(result.stderr) == [], result.stderr  # no --method: align has none
