"""A remedy is said in the reader's words: keywords for Python, options for the command line, no rewriting."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import magfit
from magfit.cli import cli
from magfit.errors import DataFileError, OptionError
from magfit.remedy import audience, command_line, for_command_line, option, options, python_call


def test_one_remedy_in_each_audience() -> None:
    assert option("unit", "uT") == "unit='uT'"
    assert option("max_samples", 100000) == "max_samples=100000"
    assert option("allow_undetermined", True) == "allow_undetermined=True"
    assert option("attitude", ["roll", "pitch", "yaw"]) == "attitude=['roll', 'pitch', 'yaw']"
    assert option("location", "52.1,4.3") == "location=(52.1, 4.3)"
    assert option("location", "LAT,LON[,ALT]") == "location=(LAT, LON[, ALT])"
    with for_command_line():
        assert audience() == "command line"
        assert option("unit", "uT") == "--unit uT"
        assert option("max_samples", 100000) == "--max-samples 100000"
        assert option("allow_undetermined", True) == "--force"
        assert option("allow_undetermined", False) == ""
        assert option("attitude", ["roll", "pitch", "yaw"]) == "--attitude roll,pitch,yaw"
        assert option("columns", "...") == "--columns X,Y,Z"
        assert options([("method", "sphere"), ("field_strength", "wmm")]) == "--method sphere --field-strength wmm"
    assert audience() == "python"
    assert options([("method", "sphere"), ("field_strength", "wmm")]) == "method='sphere', field_strength='wmm'"


def test_a_whole_call_from_the_same_pairs() -> None:
    pairs = (("method", "vector"), ("attitude", "roll,pitch,yaw"), ("allow_undetermined", "True"))
    assert python_call("f.csv", pairs) == (
        "magfit.calibrate_file('f.csv', method='vector', attitude=['roll', 'pitch', 'yaw'], allow_undetermined=True)"
    )
    assert (
        command_line("calibrate", "f.csv", pairs)
        == "magfit calibrate f.csv --method vector --attitude roll,pitch,yaw --force"
    )


def test_the_library_and_the_command_say_the_same_remedy_each_in_its_words(tmp_path: Path) -> None:
    sim = magfit.simulate(500, field_strength=50.0, hard_iron=[10.0, -20.0, 30.0], noise=0.5, seed=4)
    path = tmp_path / "mag.csv"
    np.savetxt(path, sim.samples, delimiter=",", header="mx,my,mz", comments="")
    with pytest.raises(DataFileError, match=r"sensor='ID' chooses a compass"):
        magfit.calibrate_file(path, "sphere", sensor="MAG/0")
    with pytest.raises(OptionError, match=r"field_strength='wmm' needs the samples' physical unit \(unit='uT'"):
        magfit.calibrate_file(path, "sphere", unit="counts", field_strength="wmm", location=(52.0, 4.0))
    printed = CliRunner().invoke(cli, ["calibrate", str(path), "--sensor", "MAG/0"])
    assert printed.exit_code == 2
    assert "--sensor ID chooses a compass" in printed.output and "sensor='ID'" not in printed.output
    printed = CliRunner().invoke(
        cli,
        ["calibrate", str(path), "-m", "sphere", "--unit", "counts", "--field-strength", "wmm", "--location", "52,4"],
    )
    assert printed.exit_code == 2
    assert "--field-strength wmm needs the samples' physical unit (--unit uT" in printed.output, printed.output


@pytest.mark.parametrize("location", [(52.0,), (52.0, 4.0, 0.0, 1.0), ("north", "east"), 52.0, (float("nan"), 4.0)])
def test_a_location_that_is_no_place_is_one_line(tmp_path: Path, location: object) -> None:
    path = tmp_path / "mag.csv"
    np.savetxt(path, magfit.simulate(300, seed=1).samples, delimiter=",", header="mx,my,mz", comments="")
    with pytest.raises(OptionError, match="is no place: give \\(latitude, longitude\\)"):
        magfit.calibrate_file(path, "sphere", unit="uT", location=location)  # type: ignore[arg-type]


def test_a_location_of_two_numbers_is_at_sea_level(tmp_path: Path) -> None:
    pytest.importorskip("pygeomag")
    path = tmp_path / "mag.csv"
    np.savetxt(path, magfit.simulate(300, seed=1).samples, delimiter=",", header="mx,my,mz", comments="")
    two = magfit.calibrate_file(path, "sphere", unit="uT", location=(52.0, 4.0), date="2025-01-01")
    three = magfit.calibrate_file(path, "sphere", unit="uT", location=(52.0, 4.0, 0.0), date="2025-01-01")
    assert two.model_field is not None and three.model_field is not None
    assert two.model_field.field.total == pytest.approx(three.model_field.field.total)
