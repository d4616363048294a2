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

from .alignment import Alignment, align
from .calibration import CONVENTION, Calibration
from .compare import Comparison, MethodResult
from .diagnostics import Diagnostics
from .errors import CalibrationError, DataFileError, ExportError, MagfitError, OptionError, SampleError
from .evaluate import Evaluation, evaluate, sphere_distances
from .facts import AutoChoice, GyroFacts, KnownField, Rejected, SolverStatus, VectorFacts
from .findings import REASON_CODES, Reason, Support
from .fit import diagnose, fit, refit
from .fleet import FleetResult, FleetRow, fleet
from .methods import METHODS
from .motorterm import MotorTerm
from .pipeline import CompassCalibration, FileCalibration, calibrate_file
from .pipeline.align import FileAlignment, align_file
from .simulate import DISTURBANCES, SENSORS, Scenario, Simulation, scenario, simulate
from .statistics import Statistics

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
    "MagfitError",
    "MethodResult",
    "MotorTerm",
    "OptionError",
    "Reason",
    "Rejected",
    "SampleError",
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
