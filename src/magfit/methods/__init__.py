"""Calibration methods. Importing this package registers every built-in method in :data:`METHODS`.

Each module registers its method(s) with :func:`~magfit.methods.registry.register`; to add a method,
add a module and import it below.
"""

from __future__ import annotations

from . import als, auto, diag, ellipsoid, gyro, minmax, ml, robust, sphere, vector  # noqa: F401  (registration)
from .registry import METHODS, FitInput, MethodSpec, get_method, register

__all__ = ["METHODS", "FitInput", "MethodSpec", "get_method", "register"]
