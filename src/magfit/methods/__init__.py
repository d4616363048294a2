"""Calibration methods: :data:`METHODS`, every built-in method by name, each method's module imported the
first time its entry is read (a command that fits with ``auto`` does not import ``gyro``).

Each module registers its method(s) with :func:`~magfit.methods.registry.register`; to add a built-in method,
add a module and its line in :data:`~magfit.methods.registry.BUILT_IN`.
"""

from __future__ import annotations

from .registry import METHODS, FitInput, MethodSpec, get_method, register

__all__ = ["METHODS", "FitInput", "MethodSpec", "get_method", "register"]
