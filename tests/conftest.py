"""Shared test fixtures: where the real recordings live."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

#: The real recordings sit in ../shared/data/real beside the checkout (MAGFIT_REAL_DATA overrides).
REAL_DATA_DIR = Path(
    os.environ.get("MAGFIT_REAL_DATA", Path(__file__).resolve().parents[2] / "shared" / "data" / "real")
)


@pytest.fixture(scope="session")
def real_data_dir() -> Path:
    """The folder of real recordings; skips the test when absent, except under CI where that is a failure."""
    if REAL_DATA_DIR.is_dir():
        return REAL_DATA_DIR
    if os.environ.get("CI") == "true":
        pytest.fail(f"the real recordings are missing under CI: expected {REAL_DATA_DIR}")
    pytest.skip(f"real recordings not found at {REAL_DATA_DIR} (set MAGFIT_REAL_DATA)")
