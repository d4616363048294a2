"""Start-up: what ``magfit calibrate`` on a small samples file imports, and the lazy table of methods.

Each check runs in a fresh interpreter (``sys.modules`` of this one already holds everything the suite
imported). The methods are listed by name without importing their modules; a method's module is imported the
first time its entry is read.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import magfit
from magfit.methods.registry import BUILT_IN, METHODS, MethodRegistry, register

SRC = Path(__file__).resolve().parents[1] / "src"

#: Modules a samples file fitted with the default method has no use for: the vehicle methods, the motors'
#: stage, the log readers, the plots and report, the fleet, and the heavy libraries (the small text file is
#: parsed without pandas; the fit needs no SciPy).
NOT_FOR_A_SMALL_FILE = (
    "magfit.methods.gyro",
    "magfit.methods.vector",
    "magfit.motor",
    "magfit.pipeline.motor",
    "magfit.sources.power",
    "magfit.sources.dataflash",
    "magfit.sources.ulog",
    "magfit.sources.tlog",
    "magfit.plot",
    "magfit.report",
    "magfit.fleet",
    "magfit.export",
    "pandas",
    "scipy",
    "matplotlib",
    "pyarrow",
    "concurrent.futures",
)


def _in_fresh_python(code: str) -> dict:
    """Run ``code`` (which prints one JSON line last) in a fresh interpreter with this tree's source first."""
    env_path = str(SRC)
    run = subprocess.run(
        [sys.executable, "-c", f"import sys; sys.path.insert(0, {env_path!r})\n{code}"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 0, run.stderr
    return json.loads(run.stdout.strip().splitlines()[-1])


@pytest.fixture
def small_csv(tmp_path: Path) -> tuple[Path, magfit.Calibration]:
    sim = magfit.scenario("mpu9250", "steel").simulate(300, seed=11)
    path = tmp_path / "small.csv"
    np.savetxt(path, sim.samples, delimiter=",", header="mx,my,mz", comments="", fmt="%.4f")
    return path, sim.truth


def test_calibrate_on_a_small_samples_file_imports_no_vehicle_method_no_log_reader_no_pandas(
    small_csv: tuple[Path, magfit.Calibration], tmp_path: Path
) -> None:
    path, truth = small_csv
    out = tmp_path / "cal.json"
    found = _in_fresh_python(
        "import contextlib, io, json\n"
        "from magfit.cli.app import main\n"
        "with contextlib.redirect_stdout(io.StringIO()):\n"
        f"    status = main(['calibrate', {str(path)!r}, '-o', {str(out)!r}])\n"
        "print(json.dumps({'status': status, 'modules': sorted(sys.modules)}))"
    )
    assert found["status"] == 0
    loaded = set(found["modules"])
    leaked = sorted(m for m in loaded for no in NOT_FOR_A_SMALL_FILE if m == no or m.startswith(no + "."))
    assert not leaked, f"imported by calibrate on a 300-row file: {leaked}"
    assert "magfit.methods.auto" in loaded  # (the default method: the test would pass vacuously without it)
    # And the fit it made is the truth's (the steel scenario's offset, within its noise).
    fitted = magfit.Calibration.from_json(out.read_text())
    assert fitted.method == "auto"
    assert np.linalg.norm(fitted.offset - truth.offset) < 0.02 * truth.field_strength


def test_the_methods_are_listed_without_importing_them() -> None:
    found = _in_fresh_python(
        "import json, magfit\n"
        "from magfit.cli.app import main\n"
        "import contextlib, io\n"
        "help_text = io.StringIO()\n"
        "with contextlib.redirect_stdout(help_text):\n"
        "    main(['calibrate', '--help'])\n"
        "names = list(magfit.METHODS)\n"
        "print(json.dumps({'names': names, 'contains': 'gyro' in magfit.METHODS, 'help': help_text.getvalue(),\n"
        "                  'modules': sorted(m for m in sys.modules if m.startswith('magfit.methods.'))}))"
    )
    assert found["names"] == list(BUILT_IN)
    assert found["contains"] is True
    method_modules = {METHODS.module(name) for name in BUILT_IN} | {"magfit.methods.gyro", "magfit.methods.vector"}
    assert not method_modules & set(found["modules"])  # listed, `in`, and --help: no method imported
    assert "|".join(BUILT_IN) in found["help"].replace("\n", "").replace(" ", "")


def test_every_built_in_name_is_registered_by_its_module() -> None:
    for name in BUILT_IN:
        spec = METHODS[name]
        assert spec.name == name
        assert spec.function.__module__ == METHODS.module(name)
    assert list(METHODS) == list(BUILT_IN)  # (the order the user sees, whatever was imported first)


def test_a_method_registered_at_run_time_joins_the_end_and_leaves() -> None:
    registry = METHODS
    assert "midpoint_test" not in registry

    @register("midpoint_test", min_samples=3, data="statistics", summary="a test method")
    def midpoint(data: object) -> magfit.Calibration:  # pragma: no cover - never fitted here
        raise NotImplementedError

    try:
        assert list(registry)[-1] == "midpoint_test"
        assert registry["midpoint_test"].function is midpoint
        with pytest.raises(RuntimeError, match="registered twice"):
            register("midpoint_test", min_samples=3, data="statistics", summary="again")(midpoint)
        with pytest.raises(RuntimeError, match="registered twice"):  # a built-in name, from another module
            register("gyro", min_samples=3, data="statistics", summary="not the gyro")(midpoint)
    finally:
        del registry["midpoint_test"]
    assert "midpoint_test" not in registry and list(registry) == list(BUILT_IN)
    with pytest.raises(magfit.OptionError, match="valid methods: " + ", ".join(BUILT_IN)):
        magfit.fit(np.zeros((20, 3)), "midpoint_test")


def test_a_module_that_does_not_register_its_name_is_said() -> None:
    registry = MethodRegistry({"nothing": "registry"})  # magfit.methods.registry registers no "nothing"
    assert list(registry) == ["nothing"] and "nothing" in registry
    with pytest.raises(RuntimeError, match="did not register the method 'nothing'"):
        registry["nothing"]
