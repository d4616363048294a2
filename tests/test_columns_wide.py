"""Wide files without a header: time, a magnetometer, an attitude and a reference field side by side. The
content rule never takes a reference field, angles, time or a triple drawn from several groups for the
magnetometer; where several triples stay plausible it refuses and lists them; ``magfit inspect`` says what
each group of columns was taken for."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.spatial.transform import Rotation

from magfit.cli import cli
from magfit.errors import DataFileError
from magfit.io import read_samples
from magfit.io.columns import choose_columns_by_content
from magfit.vehicle import simulate_vehicle


def flight_table(n: int, seed: int) -> np.ndarray:
    """time, flux x/y/z (nT, with the aircraft's own fields following its roll), pitch, roll, yaw (degrees,
    0-360), the reference field N/E/D (nT, drifting slowly with the place): the issue's 10 columns."""
    sim = simulate_vehicle(
        n, "flight", rate_hz=10.0, field_strength=50000.0, inclination_deg=64.0, declination_deg=3.0, noise=5.0,
        hard_iron=[800.0, -500.0, 300.0], seed=seed,
    )  # fmt: skip
    yaw, pitch, roll = Rotation.from_matrix(sim.attitude_measured).as_euler("ZYX", degrees=True).T
    rate = np.gradient(roll, sim.time_s)
    own = 600.0 * np.column_stack([3 * np.sin(np.radians(roll)), rate / 3, np.cos(np.radians(pitch)) - 1])
    drift = np.linspace(0, 1, n)[:, None] * np.array([40.0, -25.0, 60.0])
    reference = np.round(sim.field_world + drift, 1)
    return np.column_stack([sim.time_s, sim.samples + own, pitch, roll, np.mod(yaw, 360.0), reference])


def test_the_issue_s_ten_column_file_reads_the_magnetometer(tmp_path: Path) -> None:
    """Before: columns 3, 6, 7 (flux z, roll, yaw); now flux x/y/z, with the others named for what they are."""
    table = flight_table(2500, seed=1)
    path = tmp_path / "flight.csv"
    np.savetxt(path, table, delimiter=",", fmt="%.3f")
    read = read_samples(path)
    assert read.columns == ("column 2", "column 3", "column 4")
    np.testing.assert_allclose(read.samples, table[:, 1:4], atol=1e-3)
    result = CliRunner().invoke(cli, ["inspect", str(path)])
    assert result.exit_code == 0, result.output
    said = {line.split(":")[0].strip(): line for line in result.stdout.splitlines() if "column" in line}
    assert any("column 2, column 3, column 4: the magnetometer" in line for line in said.values())
    assert any("column 5, column 6, column 7: angles" in line for line in said.values())
    assert any(
        "column 8, column 9, column 10: turns by" in line and "reference field" in line for line in said.values()
    )


@pytest.mark.parametrize("seed", [0, 2, 3, 4, 5])
def test_never_a_reference_field_angles_or_a_mixed_triple(seed: int) -> None:
    head = flight_table(2000, seed=seed)
    choice = choose_columns_by_content(head, range(10))
    assert choice.indices == (1, 2, 3) or choice.rivals  # the magnetometer, or a refusal: never a guess
    assert not set(choice.indices) & {0, 7, 8, 9}
    for triple in (choice.indices, *choice.rivals):
        assert triple in {(1, 2, 3), (4, 5, 6)}  # neighbouring columns only


def test_a_body_frame_reference_with_a_constant_norm_is_passed_over() -> None:
    """A model field turned into the body frame looks like a perfect magnetometer but for its norm, constant to
    1e-9: no sensor's noise is that small. The real magnetometer beside it is chosen."""
    sim = simulate_vehicle(
        1500, "tumble", rate_hz=50.0, field_strength=50.0, noise=0.2, hard_iron=[5.0, -3.0, 2.0], seed=7
    )
    head = np.column_stack([sim.time_s, sim.reference, sim.samples])
    choice = choose_columns_by_content(head, range(7))
    assert choice.indices == (4, 5, 6)
    assert any(triple == (1, 2, 3) and "below any sensor's noise" in why for triple, why in choice.passed)


def test_several_plausible_triples_are_refused_with_their_names(tmp_path: Path) -> None:
    """A short straight leg: the angles outline an ellipsoid as well as the magnetometer does. Refused, listing
    both, rather than a guess."""
    table = flight_table(600, seed=1)
    path = tmp_path / "leg.csv"
    np.savetxt(path, table, delimiter=",", fmt="%.3f")
    with pytest.raises(DataFileError, match="several column triples look like a magnetometer") as caught:
        read_samples(path)
    assert "(column 2, column 3, column 4)" in str(caught.value) and "(column 5, column 6, column 7)" in str(
        caught.value
    )
    result = CliRunner().invoke(cli, ["inspect", str(path)])
    assert result.exit_code == 0
    assert result.stdout.count("a candidate magnetometer, as likely as another") == 2


@pytest.mark.parametrize(
    ("header", "expected"),
    [
        (
            ["TimeUS", "MagX", "MagY", "MagZ", "Roll", "Pitch", "Yaw"],
            {"time": ((0,), 1e-6), "attitude": ((4, 5, 6), 1.0)},
        ),
        (
            ["t", "mx", "my", "mz", "q0", "q1", "q2", "q3", "wmm_n", "wmm_e", "wmm_d", "lat", "lon", "alt"],
            {
                "time": ((0,), 1.0),
                "attitude": ((4, 5, 6, 7), 1.0),
                "reference": ((8, 9, 10), 1.0),
                "place": ((11, 12, 13), 1.0),
            },
        ),
        (
            ["time_ms", "gyro_x(rad/s)", "gyro_y(rad/s)", "gyro_z(rad/s)", "accX", "accY", "accZ", "Bx", "By", "Bz"],
            {"time": ((0,), 1e-3), "gyro": ((1, 2, 3), 1.0), "accel": ((4, 5, 6), 1.0)},
        ),
        (["qw", "qx", "qy", "phi", "theta"], {}),  # incomplete groups are not streams
    ],
)
def test_the_other_streams_are_found_by_name(
    header: list[str], expected: dict[str, tuple[tuple[int, ...], float]]
) -> None:
    from magfit.io.streams import find_stream_columns

    found = find_stream_columns(header)
    assert {name: (columns.indices, columns.scale) for name, columns in found.items()} == expected
