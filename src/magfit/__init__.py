"""magfit: magnetometer calibration.

Model (paper, eq. 1): ``B_p = W R B (cos δ, 0, sin δ)ᵀ + V``. Every calibration undoes it as
``corrected = matrix @ (raw - offset)``, which lies on a sphere of radius ``field_strength``.

>>> import magfit
>>> sim = magfit.scenario("mpu9250", "steel").simulate(2000, seed=1)
>>> cal = magfit.fit(sim.samples, method="ellipsoid")
>>> magfit.evaluate(cal, sim.samples).std < 0.05
True
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
import types
from typing import TYPE_CHECKING, Any

from .errors import CalibrationError, DataFileError, ExportError, MagfitError, OptionError, SampleError

if TYPE_CHECKING:  # what type checkers and IDEs see; at run time each name is imported on first use
    from .alignment import Alignment, align
    from .calibration import CONVENTION, Calibration
    from .compare import Comparison, MethodResult
    from .diagnostics import Diagnostics
    from .evaluate import Evaluation, evaluate, sphere_distances
    from .facts import AutoChoice, GyroFacts, KnownField, LogCompass, Rejected, SampleSource, SolverStatus, VectorFacts
    from .findings import REASON_CODES, Reason, Support
    from .fit import diagnose, fit, refit
    from .fleet import FleetResult, FleetRow, fleet
    from .methods import METHODS
    from .motorterm import MotorTerm
    from .pipeline import CompassCalibration, FileCalibration, calibrate_file
    from .pipeline.align import FileAlignment, align_file
    from .simulate import DISTURBANCES, SENSORS, Scenario, Simulation, scenario, simulate
    from .statistics import Statistics

#: Where each public name lives: ``magfit.X`` imports its module the first time X is asked for, so that
#: ``import magfit`` (and ``import magfit.cli``, whose commands import what they run) costs little.
_LAZY = {
    "Alignment": "alignment",
    "align": "alignment",
    "CONVENTION": "calibration",
    "Calibration": "calibration",
    "Comparison": "compare",
    "MethodResult": "compare",
    "Diagnostics": "diagnostics",
    "Evaluation": "evaluate",
    "evaluate": "evaluate",
    "sphere_distances": "evaluate",
    "REASON_CODES": "findings",
    "Reason": "findings",
    "Support": "findings",
    "diagnose": "fit",
    "fit": "fit",
    "refit": "fit",
    "FleetResult": "fleet",
    "FleetRow": "fleet",
    "fleet": "fleet",
    "METHODS": "methods",
    "MotorTerm": "motorterm",
    "CompassCalibration": "pipeline",
    "FileCalibration": "pipeline",
    "calibrate_file": "pipeline",
    "FileAlignment": "pipeline.align",
    "align_file": "pipeline.align",
    "AutoChoice": "facts",
    "GyroFacts": "facts",
    "KnownField": "facts",
    "LogCompass": "facts",
    "Rejected": "facts",
    "SampleSource": "facts",
    "SolverStatus": "facts",
    "VectorFacts": "facts",
    "DISTURBANCES": "simulate",
    "SENSORS": "simulate",
    "Scenario": "simulate",
    "Simulation": "simulate",
    "scenario": "simulate",
    "simulate": "simulate",
    "Statistics": "statistics",
}


def __getattr__(name: str) -> Any:
    """``magfit.X`` for a public name: imported from its module on first use, then kept in the package."""
    module = _LAZY.get(name)
    if module is None:
        # A submodule (magfit.sampling, magfit.diagnostics, ...), as the eager imports used to leave them.
        if not name.startswith("_") and importlib.util.find_spec(f"{__name__}.{name}") is not None:
            return importlib.import_module(f".{name}", __name__)
        raise AttributeError(f"module 'magfit' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


class _Package(types.ModuleType):
    """The package's module type: ``fit``, ``simulate``, ``evaluate`` and ``fleet`` are both a public function
    and the submodule that defines it. Importing the submodule binds it on the package under the same name;
    the eager imports bound the function over it afterwards. Here a property keeps the name the function's:
    a submodule bound to it is set aside, any other value (a test's stand-in) is kept.
    """


def _public_function(name: str) -> property:
    replaced: dict[str, Any] = {}

    def get(package: types.ModuleType) -> Any:
        if "value" in replaced:
            return replaced["value"]
        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)

    def set_(package: types.ModuleType, value: Any) -> None:
        if not isinstance(value, types.ModuleType):
            replaced["value"] = value

    def delete(package: types.ModuleType) -> None:
        replaced.pop("value", None)

    return property(get, set_, delete)


for _name in ("fit", "simulate", "evaluate", "fleet"):
    setattr(_Package, _name, _public_function(_name))
sys.modules[__name__].__class__ = _Package


__version__ = "0.1.0"

__all__ = [
    "CONVENTION",
    "DISTURBANCES",
    "METHODS",
    "REASON_CODES",
    "SENSORS",
    "Alignment",
    "AutoChoice",
    "Calibration",
    "CalibrationError",
    "Comparison",
    "CompassCalibration",
    "DataFileError",
    "Diagnostics",
    "Evaluation",
    "ExportError",
    "FileAlignment",
    "FileCalibration",
    "FleetResult",
    "FleetRow",
    "GyroFacts",
    "KnownField",
    "LogCompass",
    "MagfitError",
    "MethodResult",
    "MotorTerm",
    "OptionError",
    "Reason",
    "Rejected",
    "SampleError",
    "SampleSource",
    "Scenario",
    "Simulation",
    "SolverStatus",
    "Statistics",
    "Support",
    "VectorFacts",
    "__version__",
    "align",
    "align_file",
    "calibrate_file",
    "diagnose",
    "evaluate",
    "fit",
    "fleet",
    "refit",
    "scenario",
    "simulate",
    "sphere_distances",
]
