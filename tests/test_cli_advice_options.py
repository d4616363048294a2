"""Each command's advice names only options it has, or the command that has them (``magfit calibrate FILE
--method vector``): ``magfit compare`` says ``--methods``, ``magfit inspect`` (which takes no option) says
every remedy through ``magfit calibrate``, and a Python caller gets keywords. Following the advice works."""

from __future__ import annotations

import json
import re
from pathlib import Path

import click
import numpy as np
import pytest
from click.testing import CliRunner

import magfit
from magfit.cli import cli
from magfit.compare import compare
from magfit.remedy import for_command, for_command_line, option, options

TRUE_OFFSET = np.array([10.0, -5.0, 3.0])
TRUE_SOFT = np.diag([1.1, 0.95, 1.0])
_FLAG = re.compile(r"(?<![\w-])--[a-z][a-z-]*")
_NAMED = re.compile(r"\bmagfit ([a-z]+)\b")


def _flags(command: str) -> set[str]:
    found = cli.get_command(click.Context(cli), command)
    assert found is not None, f"advice names 'magfit {command}', which is no command"
    return {name for p in found.params for name in (*p.opts, *p.secondary_opts) if name.startswith("--")}


def _assert_flags_exist(output: str, command: str) -> int:
    """Every ``--flag`` in ``output`` is an option of ``command``, or of the command the same line names last
    before it (``magfit calibrate FILE --method vector``). Returns how many flags were checked."""
    checked = 0
    for line in output.splitlines():
        for match in _FLAG.finditer(line):
            named = _NAMED.findall(line[: match.start()])
            owner = named[-1] if named else command
            assert match.group() in _flags(owner), f"{match.group()} is no option of magfit {owner}: {line.strip()}"
            checked += 1
    return checked


def _simulation(orientations: str = "uniform", seed: int = 1) -> np.ndarray:
    return magfit.simulate(
        600, hard_iron=TRUE_OFFSET, soft_iron=TRUE_SOFT, field_strength=50.0, noise=0.3, orientations=orientations,
        seed=seed,
    ).samples  # fmt: skip


@pytest.fixture
def files(tmp_path: Path) -> dict[str, Path]:
    tumble, yaw = _simulation(), _simulation("yaw", seed=2)
    paths = {name: tmp_path / name for name in ("tumble.csv", "yaw.csv", "streams.csv", "four.npz", "four2.npz")}
    np.savetxt(paths["tumble.csv"], tumble, delimiter=",", header="mag_x,mag_y,mag_z", comments="")
    np.savetxt(paths["yaw.csv"], yaw, delimiter=",", header="mag_x,mag_y,mag_z", comments="")
    table = np.column_stack([np.arange(600) * 0.1, tumble, np.zeros((600, 3))])
    header = "time,mag_x,mag_y,mag_z,roll,pitch,yaw"
    np.savetxt(paths["streams.csv"], table, delimiter=",", header=header, comments="")
    np.savez(paths["four.npz"], mag=np.column_stack([tumble, np.ones(600)]))
    np.savez(paths["four2.npz"], mag=np.column_stack([tumble, np.ones(600)]), other=np.ones((600, 5)))
    return paths


def test_compare_says_how_to_give_a_vehicle_methods_streams_in_options_that_exist(files: dict[str, Path]) -> None:
    result = CliRunner().invoke(cli, ["compare", str(files["tumble.csv"]), "--methods", "vector,gyro,ellipsoid"])
    assert result.exit_code == 0, result.output  # ellipsoid ran
    assert _assert_flags_exist(result.output, "compare") >= 4
    assert "reference=" not in result.output and "gyro=" not in result.output  # no Python keyword on the command line
    assert "magfit calibrate FILE --method vector --reference X,Y,Z" in result.output


def test_compare_names_its_own_methods_option_for_another_method(files: dict[str, Path]) -> None:
    result = CliRunner().invoke(cli, ["compare", str(files["yaw.csv"]), "--methods", "ellipsoid,als,diag"])
    assert result.exit_code == 1, result.output  # no method is supported by a yaw-only recording
    assert _assert_flags_exist(result.output, "compare") >= 3
    assert "--methods sphere" in result.output and "--method " not in result.output


def test_compare_on_an_npz_array_of_four_columns_gives_advice_that_works(files: dict[str, Path]) -> None:
    runner = CliRunner()
    refused = runner.invoke(cli, ["compare", str(files["four.npz"]), "--columns", "mag"])
    assert refused.exit_code == 2 and "Traceback" not in refused.output
    assert _assert_flags_exist(refused.output, "compare") == 1
    assert "[:, " not in refused.output and "--columns 0,1,2" in refused.output
    followed = runner.invoke(cli, ["compare", str(files["four.npz"]), "--columns", "0,1,2", "--format", "json"])
    assert followed.exit_code == 0, followed.output
    # the advice reached the magnetometer: the ellipsoid fit recovers the simulated offset
    fitted = {entry["method"]: entry for entry in json.loads(followed.stdout)[0]["results"]}
    offset = magfit.Calibration.from_dict(fitted["ellipsoid"]["calibration"]).offset
    np.testing.assert_allclose(offset, TRUE_OFFSET, atol=0.2)
    # with another 2-D array beside it, numbers would be ambiguous: the command line's way is named
    several = runner.invoke(cli, ["compare", str(files["four2.npz"]), "--columns", "mag"])
    assert several.exit_code == 2 and "[:, " not in several.output
    assert _assert_flags_exist(several.output, "compare") == 1 and "--columns mag_x,mag_y,mag_z" in several.output


@pytest.mark.parametrize("name", ["streams.csv", "four.npz", "four2.npz"])
def test_inspect_says_every_remedy_through_the_command_that_has_it(files: dict[str, Path], name: str) -> None:
    result = CliRunner().invoke(cli, ["inspect", str(files[name])])
    assert result.exit_code == 0, result.output
    assert _assert_flags_exist(result.output, "inspect") >= 1  # inspect has none: each is calibrate's
    assert f"magfit calibrate {files[name]} --" in result.output


def test_inspect_on_a_log_of_several_compasses_names_calibrates_sensor_option() -> None:
    log = Path(__file__).parent / "data" / "ardupilot_sitl" / "sitl_three_compasses.bin"
    result = CliRunner().invoke(cli, ["inspect", str(log)])
    assert result.exit_code == 0, result.output
    assert _assert_flags_exist(result.output, "inspect") == 1
    assert f"magfit calibrate {log} fits each" in result.output and "--sensor ID" in result.output


def test_a_python_caller_gets_keywords_that_work(files: dict[str, Path]) -> None:
    samples = np.loadtxt(files["tumble.csv"], delimiter=",", skiprows=1)
    comparison = compare(samples, ["vector", "ellipsoid"])
    error = comparison.results[0].error
    assert error is not None and "streams={'reference': ...}" in error and "--" not in error
    with pytest.raises(magfit.DataFileError) as refused:
        magfit.calibrate_file(files["four2.npz"], "ellipsoid", columns=["mag"])
    message = str(refused.value)
    assert "columns=['mag[:, 0]', 'mag[:, 1]', 'mag[:, 2]']" in message and "--" not in message
    followed = magfit.calibrate_file(files["four2.npz"], "ellipsoid", columns=["mag[:, 0]", "mag[:, 1]", "mag[:, 2]"])
    np.testing.assert_allclose(followed.calibration.offset, TRUE_OFFSET, atol=0.2)


def test_for_command_renders_an_option_the_command_has_lacks_or_renames() -> None:
    assert option("method", "sphere") == "method='sphere'"  # Python: keywords, whatever the command
    with for_command_line():
        with for_command("compare", ["--columns", "--force", "--methods"], renamed={"--method": "--methods"}):
            assert option("method", "sphere") == "--methods sphere"
            assert option("columns", ["a", "b", "c"]) == "--columns a,b,c"
            assert option("allow_undetermined", True) == "--force"
            assert option("unit", "uT") == "magfit calibrate FILE --unit uT"
            assert options([("method", "vector"), ("attitude", "...")]) == (
                "magfit calibrate FILE --method vector --attitude X,Y,Z"
            )
        with for_command("inspect", [], file="m.csv"):
            assert option("allow_undetermined", False) == ""  # a flag not given is not said
            assert option("sensor", "ID") == "magfit calibrate m.csv --sensor ID"
        assert option("method", "sphere") == "--method sphere"  # outside: the command line's own words
