"""A recording to calibrations: :func:`calibrate_file`, what ``magfit calibrate`` runs, for Python users too.

One direction: the file is opened once as a source (:mod:`magfit.sources` for flight logs and bags,
:mod:`magfit.io` for samples files), each compass's samples are fitted (:func:`magfit.fit`, in bounded
memory for big samples files: :mod:`magfit.pipeline.streaming`) and scored (:func:`magfit.evaluate`), and the
World Magnetic Model's field (:mod:`magfit.geomag`) is looked up where and when the recording was made — at
the place given, or at the log's own GNSS fixes. Nothing here prints: notes reach the caller in the result
(and, as they are found, through ``notify``); errors are magfit's own exceptions.

>>> import magfit, numpy as np, tempfile, pathlib
>>> sim = magfit.simulate(2000, field_strength=50.0, hard_iron=[10.0, -20.0, 30.0], noise=0.5, seed=4)
>>> path = pathlib.Path(tempfile.mkdtemp()) / "mag.csv"
>>> np.savetxt(path, sim.samples, delimiter=",", header="mx,my,mz", comments="")
>>> result = magfit.calibrate_file(path, method="sphere", unit="uT")
>>> [round(float(v)) for v in result.calibration.offset]
[10, -20, 30]
"""

from .advice import RefusedWithAdvice, StreamsMissing
from .calibrate import calibrate_file
from .results import CompassCalibration, CompassFailure, FileCalibration, ModelField
from .streaming import Progress, no_progress
from .table import StreamSpec

__all__ = [
    "CompassCalibration",
    "CompassFailure",
    "FileCalibration",
    "ModelField",
    "Progress",
    "RefusedWithAdvice",
    "StreamSpec",
    "StreamsMissing",
    "calibrate_file",
    "no_progress",
]
