"""``import magfit`` is light: the public names are imported on first use, and every one of them works."""

from __future__ import annotations

import subprocess
import sys

import pytest

import magfit


def _run(code: str) -> str:
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120)
    return result.stdout.strip()


def test_import_magfit_loads_no_numerics() -> None:
    loaded = _run(
        "import sys, magfit; "
        "print(sorted(m for m in sys.modules if m.split('.')[0] in {'numpy', 'scipy'} or m == 'magfit.fit'))"
    )
    assert loaded == "[]"


def test_every_public_name_resolves_and_is_listed() -> None:
    for name in magfit.__all__:
        assert getattr(magfit, name) is not None, name
    assert set(magfit.__all__) <= set(dir(magfit))
    assert magfit.fit is __import__("magfit.fit", fromlist=["fit"]).fit


def test_star_import_and_submodules() -> None:
    names = _run("from magfit import *; print(callable(fit) and callable(Statistics.from_samples))")
    assert names == "True"
    assert _run("import magfit; print(magfit.sampling.thin(10, 1).size)") == "10"


def test_unknown_name_is_an_attribute_error() -> None:
    try:
        magfit.no_such_name  # noqa: B018
    except AttributeError as error:
        assert "no_such_name" in str(error)
    else:
        raise AssertionError("magfit.no_such_name did not raise")


def test_a_function_named_as_its_module_stays_the_function() -> None:
    code = (
        "import magfit, magfit.fit, magfit.simulate, magfit.evaluate, magfit.fleet, types; "
        "print([isinstance(getattr(magfit, n), types.FunctionType) for n in ('fit', 'simulate', 'evaluate', 'fleet')])"
    )
    assert _run(code) == "[True, True, True, True]"


def test_a_stand_in_for_fit_is_kept(monkeypatch: pytest.MonkeyPatch) -> None:
    def stand_in(*args: object, **kwargs: object) -> str:
        return "stand-in"

    monkeypatch.setattr(magfit, "fit", stand_in)
    assert magfit.fit() == "stand-in"
    monkeypatch.undo()
    assert magfit.fit is not stand_in
