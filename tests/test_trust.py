"""The support verdict (issue 10): no method returns a calibration the samples do not support.

Each case below is data a real user records by mistake or by necessity: a sensor that only yaws, a
vehicle that barely tilts, a still sensor, a barely moving one, data on no ellipsoid at all (a cloud, a
cube), samples along a line, a field strength given in the wrong unit. Every method either refuses
(:class:`magfit.CalibrationError`, naming what is missing and what to record) or returns a calibration
whose warnings name the weakness. Never a silent number.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import magfit
from magfit import CalibrationError

# The methods that run on samples alone (vector needs a reference field: tests/test_vector.py).
METHODS = sorted(name for name, spec in magfit.METHODS.items() if not spec.needs)
SRC = Path(__file__).resolve().parents[1] / "src" / "magfit"


def _still(rng: np.random.Generator) -> np.ndarray:
    return np.array([0.21, -0.05, 0.43]) + 0.002 * rng.normal(size=(800, 3))  # gauss, a sensor on a desk


def _barely_moving(rng: np.random.Generator) -> np.ndarray:
    attitudes = np.column_stack([rng.normal(0, 3, 800), rng.normal(0, 3, 800), rng.normal(30, 3, 800)])
    return magfit.simulate(800, hard_iron=[0.3, -0.2, 0.1], noise=0.005, orientations=attitudes, seed=2).samples


def _line(rng: np.random.Generator) -> np.ndarray:
    t = rng.uniform(-1, 1, 800)
    return np.column_stack([t, 2 * t, -t]) + 1e-6 * rng.normal(size=(800, 3))


CASES = {
    "yaw-only": lambda rng: magfit.simulate(800, orientations="yaw", noise=0.01, seed=1).samples,
    "tilt ±5°": lambda rng: magfit.simulate(
        800, hard_iron=[0.2, 0.1, -0.3], orientations="restricted", max_tilt_deg=5, noise=0.01, seed=1
    ).samples,
    "still": _still,
    "barely moving": _barely_moving,
    "gaussian cloud": lambda rng: rng.normal(size=(800, 3)),
    "filled cube": lambda rng: rng.uniform(-1, 1, size=(800, 3)),
    "line": _line,
}
#: What a refusal or a warning must name, per case (any one of the alternatives).
NAMED = {
    "yaw-only": ("about z", "close to a plane", "hardly vary along z", "not an ellipsoid"),
    "tilt ±5°": ("along z", "close to a plane", "biased", "not an ellipsoid", "hardly vary", "field strength"),
    "still": ("no ellipsoid", "not an ellipsoid", "do not determine", "hardly vary"),
    "barely moving": ("not an ellipsoid", "about", "do not determine", "no ellipsoid", "biased", "hardly vary"),
    "gaussian cloud": ("no ellipsoid", "not an ellipsoid", "cannot describe"),
    "filled cube": ("no ellipsoid", "not an ellipsoid", "cannot describe"),
    "line": ("line", "do not span three dimensions"),
}


@pytest.mark.parametrize("case", sorted(CASES))
@pytest.mark.parametrize("method", METHODS)
@pytest.mark.slow
def test_unsupported_data_are_refused_or_named(method: str, case: str) -> None:
    samples = CASES[case](np.random.default_rng(7))
    try:
        calibration = magfit.fit(samples, method=method, diagnostics=False)
    except CalibrationError as error:
        message = str(error)
        assert any(word in message for word in NAMED[case]), message
        assert "\n" not in message
        return
    # Returned: only with the weakness named in its verdict.
    support = calibration.support.to_dict()
    assert support["verdict"] == "weak", (method, case, support)
    assert any(word in w for w in support["weaknesses"] for word in NAMED[case] + ("weakly determined",)), support


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.slow
def test_a_field_strength_in_the_wrong_unit_is_refused_by_every_method_that_takes_one(method: str) -> None:
    if "field_strength" not in magfit.METHODS[method].options:
        pytest.skip(f"{method} takes no field strength")
    sim = magfit.simulate(1500, field_strength=50.0, hard_iron=[10.0, -20.0, 30.0], noise=0.5, seed=2)  # µT
    for wrong in (500.0, 5.0):  # mG for µT, and a tenth
        with pytest.raises(CalibrationError, match="field strength given|given field strength") as caught:
            magfit.fit(sim.samples, method=method, field_strength=wrong)
        if method != "sphere":  # the sphere's own check words it as a moved centre
            assert "unit mix-up" in str(caught.value) and "mG" in str(caught.value)
    magfit.fit(sim.samples, method=method, field_strength=52.0)  # a model's value 4 % off: accepted


def test_a_forced_calibration_carries_its_refusal() -> None:
    samples = magfit.simulate(2000, orientations="yaw", noise=0.01, seed=1).samples
    with pytest.raises(CalibrationError):
        magfit.fit(samples, "sphere")
    forced = magfit.fit(samples, "sphere", allow_undetermined=True)
    support = forced.support.to_dict()
    assert support["verdict"] == "refused" and support["forced"]
    assert forced.diagnostics is not None
    assert forced.diagnostics.warnings[0].startswith("NOT SUPPORTED (forced): the sensor only turned about z")
    assert magfit.Calibration.from_json(forced.to_json()) == forced


def test_the_verdict_without_diagnostics_still_refuses() -> None:
    samples = magfit.simulate(2000, orientations="yaw", noise=0.01, seed=1).samples
    for method in ("ellipsoid", "ml", "als", "diag", "robust"):
        with pytest.raises(CalibrationError):
            magfit.fit(samples, method, diagnostics=False)


@pytest.mark.slow
def test_a_supported_tumble_says_so() -> None:
    sim = magfit.scenario("mpu9250", "smartphone").simulate(3000, seed=3)
    for method in ("ellipsoid", "als", "ml", "auto", "robust"):
        calibration = magfit.fit(sim.samples, method)
        assert calibration.support.verdict == "supported", calibration.support.to_dict()
        assert calibration.diagnostics is not None and calibration.diagnostics.ok


def test_a_recording_from_statistics_gets_a_verdict_too() -> None:
    yaw = magfit.simulate(2000, orientations="yaw", noise=0.01, seed=1).samples
    with pytest.raises(CalibrationError):
        magfit.fit(magfit.Statistics.from_samples(yaw), "ellipsoid")
    tumble = magfit.simulate(2000, noise=0.01, seed=1).samples
    calibration = magfit.fit(magfit.Statistics.from_samples(tumble), "ellipsoid")
    assert calibration.support.verdict == "supported"


# ---------------------------------------------------------------------- auto on a vehicle that cannot tumble


def _mild_soft_iron(rng: np.random.Generator) -> np.ndarray:
    matrix = np.diag(1 + rng.uniform(-0.02, 0.02, 3))  # scales within ±2 %, cross terms within ±1 %
    for (i, j), value in zip(((0, 1), (0, 2), (1, 2)), rng.uniform(-0.01, 0.01, 3), strict=True):
        matrix[i, j] = matrix[j, i] = value
    return matrix


def _level_heading_error_deg(calibration: magfit.Calibration, sim: magfit.Simulation) -> float:
    yaw = np.arange(360.0)
    raw = sim.distort(np.column_stack([np.zeros(360), np.zeros(360), yaw]))
    fitted, true = calibration.apply(raw), sim.truth.apply(raw)
    # Only A = MᵀM is identifiable: turn the fit onto the truth by the best rotation first.
    left, _, right = np.linalg.svd(sim.truth.matrix @ np.linalg.inv(calibration.matrix))
    fitted = fitted @ (left @ right).T
    difference = np.degrees(np.arctan2(fitted[:, 1], fitted[:, 0]) - np.arctan2(true[:, 1], true[:, 0]))
    return float(np.sqrt(np.mean(((difference + 180.0) % 360.0 - 180.0) ** 2)))


@pytest.mark.slow
def test_auto_on_level_flight_with_a_drifting_field_is_near_the_best_model_and_beats_none() -> None:
    # Level flight with banked turns (±15°) and a field strength drifting by ±0.5 % along the recording:
    # the BIC alone picks the full model (3.6° here, 4.4 times the best); auto must stay near the best of
    # sphere, diag and full (all three forced) and never do worse than no calibration.
    from magfit.methods.auto import fit_chosen

    errors: dict[str, list[float]] = {"auto": [], "sphere": [], "diag": [], "full": [], "none": []}
    for seed in range(3):
        rng = np.random.default_rng(100 + seed)
        sim = magfit.simulate(
            6000, soft_iron=_mild_soft_iron(rng), hard_iron=rng.uniform(-0.4, 0.4, 3), noise=0.005,
            orientations="flight", max_tilt_deg=15, field_drift=0.005, seed=seed,
        )  # fmt: skip
        auto = magfit.fit(sim.samples, "auto", diagnostics=False)
        errors["auto"].append(_level_heading_error_deg(auto, sim))
        errors["none"].append(_level_heading_error_deg(magfit.Calibration("none", np.zeros(3), np.eye(3), 1.0), sim))
        for model in ("sphere", "diag", "full"):
            try:
                errors[model].append(_level_heading_error_deg(fit_chosen(model, sim.samples), sim))
            except CalibrationError:
                errors[model].append(np.inf)
    rms = {name: float(np.sqrt(np.mean(np.square(values)))) for name, values in errors.items()}
    best = min(rms[model] for model in ("sphere", "diag", "full"))
    assert rms["auto"] <= 1.2 * best, rms
    assert all(a < n for a, n in zip(errors["auto"], errors["none"], strict=True)), errors


# ---------------------------------------------------------------------- honest uncertainty on real recordings

#: Real recordings that are time series, with the magnetometer columns (see shared/data/real/README.md).
TIME_SERIES = ("fxos", "unc", "betaflight03", "betaflight00", "mxl_imu", "mxl_pni", "gyrolib", "hamagure1", "ensta")


@pytest.mark.parametrize("name", TIME_SERIES)
def test_the_halves_of_a_recording_agree_within_their_stated_uncertainty_or_the_change_is_named(
    real_data_dir: Path, name: str
) -> None:
    sys.path.insert(0, str(Path(__file__).parent))
    from test_real_recordings import load

    samples = load(real_data_dir, name)
    middle = samples.shape[0] // 2
    halves = (samples[:middle], samples[middle:])
    first, second = (magfit.fit(half, "ellipsoid", allow_undetermined=True) for half in halves)
    sigmas = []
    for half in (first, second):
        assert half.diagnostics is not None and half.diagnostics.uncertainty is not None
        sigmas.append(np.asarray(half.diagnostics.uncertainty.offset_sigma))
    deviation = float(np.max(np.abs(first.offset - second.offset) / np.hypot(*sigmas)))
    if deviation <= 3.5:
        return
    # Beyond that, the whole recording's own diagnosis must say that its halves disagree.
    whole = magfit.fit(samples, "ellipsoid", allow_undetermined=True)
    assert whole.diagnostics is not None
    assert any("two halves of the recording" in w for w in whole.diagnostics.warnings), (name, deviation)


def test_correlated_samples_widen_the_uncertainty() -> None:
    # The same 1000 attitudes held for 20 samples each (sample-and-hold at 20x the rate): 20 000 samples
    # carry the information of about 1000, and the stated one-sigma must say so.
    sim = magfit.simulate(1000, hard_iron=[0.2, -0.1, 0.3], noise=0.01, seed=5)
    held = np.repeat(sim.samples, 20, axis=0)
    independent = magfit.simulate(20_000, hard_iron=[0.2, -0.1, 0.3], noise=0.01, seed=5).samples
    sigma_held = magfit.fit(held, "ellipsoid").diagnostics.uncertainty.offset_sigma  # type: ignore[union-attr]
    sigma_free = magfit.fit(independent, "ellipsoid").diagnostics.uncertainty.offset_sigma  # type: ignore[union-attr]
    ratio = np.asarray(sigma_held) / np.asarray(sigma_free)
    assert np.all(ratio > 2.5), ratio  # √20 ≈ 4.5 in theory; measured 3.6-4.3


# ---------------------------------------------------------------------- one direction


def _imports(path: Path, module: str) -> set[str]:
    package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[: len(parts) - node.level + 1] + ([base] if base else []))
            found.update([base, *(f"{base}.{alias.name}" for alias in node.names)])
        elif isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
    return found


@pytest.mark.slow
def test_the_package_imports_in_one_direction() -> None:
    modules: dict[str, Path] = {}
    for path in SRC.rglob("*.py"):
        name = ".".join(("magfit", *path.relative_to(SRC).with_suffix("").parts))
        modules[name.removesuffix(".__init__")] = path
    def own_package(name: str) -> str:
        return name if modules[name].name == "__init__.py" else name.rsplit(".", 1)[0]

    edges = {
        name: {
            target
            for target in _imports(path, name)
            if target in modules
            and target != name
            and not (target == own_package(name) and name.startswith(target + "."))
        }
        for name, path in modules.items()
    }
    # Depth-first search for a cycle; report the first one found as a chain of modules.
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for target in sorted(edges[node]):
            if state.get(target) == 1:
                return [*stack[stack.index(target) :], target]
            if target not in state and (cycle := visit(target)):
                return cycle
        stack.pop()
        state[node] = 2
        return None

    for module in sorted(modules):
        if module not in state and (cycle := visit(module)):
            pytest.fail("import cycle: " + " -> ".join(cycle))
    # And the layers the architecture names: the diagnostics never import the methods.
    for name, targets in edges.items():
        if name.startswith("magfit.diagnostics"):
            assert not any(t.startswith("magfit.methods") for t in targets), (name, targets)
        if name.startswith("magfit.geometry"):
            assert not any(t.startswith(("magfit.methods", "magfit.diagnostics")) for t in targets), (name, targets)


def test_refits_use_the_options_the_user_gave() -> None:
    # A sphere with a known field is cross-validated as the pinned sphere it is, not as a free one.
    from magfit.fit import refit_of

    sim = magfit.simulate(1500, field_strength=50.0, hard_iron=[10.0, -20.0, 30.0], noise=0.5, seed=2)
    calibration = magfit.fit(sim.samples, "sphere", field_strength=48.0)
    assert calibration.options == {"field_strength": 48.0}
    refit = refit_of(calibration, "sphere", calibration.options)
    again = refit(sim.samples[::2])
    assert again.field_strength == 48.0 and again.known_field.pinned
    # Every option is recorded, the defaults included, so magfit.diagnose refits exactly the same method.
    assert magfit.fit(sim.samples, "minmax").options == {"centre": "mean"}
    report = magfit.diagnose(calibration, sim.samples)
    assert report.goodness is not None and report.goodness.held_out is not None


def test_diagnose_does_not_rejudge_a_vector_calibration_by_the_field_magnitude_alone() -> None:
    # A flight covers a few percent of the directions: judged by |field| alone its calibration would be
    # refused, which contradicts the verdict the reference gave it. diagnose says where the verdict is.
    from magfit.vehicle import simulate_vehicle

    sim = simulate_vehicle(3000, "flight", rate_hz=10.0, noise=0.005, attitude_noise_deg=0.5, seed=1)
    calibration = magfit.fit(sim.samples, "vector", reference=sim.reference, time_s=sim.time_s)
    assert calibration.diagnostics is not None and calibration.diagnostics.support.verdict != "refused"
    with pytest.raises(magfit.OptionError, match="rests on reference: its verdict, made when it was fitted, is calibr"):
        magfit.diagnose(calibration, sim.samples)


def test_refit_of_a_vector_calibration_takes_the_new_samples_reference() -> None:
    from magfit.vehicle import simulate_vehicle

    sim = simulate_vehicle(3000, "flight", rate_hz=10.0, noise=0.005, attitude_noise_deg=0.2, seed=4)
    first = magfit.fit(sim.samples[:1500], "vector", reference=sim.reference[:1500], time_s=sim.time_s[:1500])
    with pytest.raises(magfit.OptionError, match=r"own reference and time_s: magfit.refit\(calibration, samples, "):
        magfit.refit(first, sim.samples[1500:])
    with pytest.raises(magfit.OptionError, match="not gyro"):
        magfit.refit(first, sim.samples[1500:], reference=sim.reference[1500:], time_s=sim.time_s, gyro=sim.gyro)
    again = magfit.refit(first, sim.samples[1500:], reference=sim.reference[1500:], time_s=sim.time_s[1500:])
    assert again.frame == "vehicle" and again.diagnostics is not None
    # Exactly the second half's own fit with the recorded options.
    fresh = magfit.fit(sim.samples[1500:], "vector", reference=sim.reference[1500:], time_s=sim.time_s[1500:])
    np.testing.assert_allclose(again.offset, fresh.offset, atol=1e-12)
    np.testing.assert_allclose(again.matrix, fresh.matrix, atol=1e-12)
    assert np.linalg.norm(again.offset - first.offset) > 0  # it did refit
    assert again.options["reference"] == "an array of 1500 rows"


def test_refit_follows_new_samples_with_the_same_model_and_a_new_verdict() -> None:
    sim = magfit.simulate(4000, soft_iron=np.diag([1.1, 0.95, 1.0]), hard_iron=[0.3, 0.1, -0.2], noise=0.01, seed=3)
    first = magfit.fit(sim.samples[:1500], "auto", diagnostics="quick")
    assert first.diagnostics is not None and first.diagnostics.uncertainty is not None
    assert first.diagnostics.goodness is None  # quick: no held-out refits
    again = magfit.refit(first, sim.samples[1500:])
    assert again.method == "auto" and again.auto.model == first.auto.model
    assert again.support.verdict == "supported"
    np.testing.assert_allclose(again.offset, sim.truth.offset, atol=0.005)
    # A refit is judged too: new samples that only yaw do not support it.
    yaw = magfit.simulate(2000, orientations="yaw", noise=0.01, seed=1, hard_iron=[0.3, 0.1, -0.2]).samples
    with pytest.raises(CalibrationError):
        magfit.refit(magfit.fit(sim.samples, "ellipsoid"), yaw)


def _generic_sensor(n: int, noise: float, tilt_deg: float) -> magfit.Simulation:
    """The benchmark's generic sensor (semi-axes 1.25 / 1.0 / 0.8 turned 30°), tilted within ±tilt_deg."""
    rotation = Rotation.from_rotvec(np.radians(30.0) * np.array([1.0, 2.0, 3.0]) / np.sqrt(14.0)).as_matrix()
    soft_iron = rotation @ np.diag([1.25, 1.0, 0.8]) @ rotation.T
    return magfit.simulate(
        n, soft_iron=soft_iron, hard_iron=[0.5, -0.3, 0.8], noise=noise, orientations="restricted",
        max_tilt_deg=tilt_deg, seed=0,
    )  # fmt: skip


def test_auto_returns_the_full_model_near_the_attitudes_recorded_and_says_so() -> None:
    # Tilted ±20°: the sphere fits the cap to 2.8 % but leaves 10° of heading error; the full ellipsoid does
    # not pin its z scale apart from its z offset (one-sigma ~20 % of the field), but pins the level heading
    # to ±1.3°: returned, weak, saying what it holds for.
    sim = _generic_sensor(1000, 0.02, 20.0)
    calibration = magfit.fit(sim.samples, "auto")
    report = calibration.diagnostics
    assert report is not None and report.support is not None and report.uncertainty is not None
    assert calibration.auto.chosen == "full" and report.support.verdict == "weak"
    named = [w for w in report.support.weaknesses if "do not determine the scale along z together with the offset" in w]
    assert named and "holds only near the attitudes recorded" in named[0]
    assert calibration.auto.reason.startswith("full model: not determined in every direction, returned because")
    stated = report.uncertainty.heading_sigma_deg
    assert stated is not None and _level_heading_error_deg(calibration, sim) < 2.0 * stated < 6.0


def test_auto_refuses_a_determined_model_that_misses_the_distortion() -> None:
    # Tilted ±12° with fewer, noisier samples: neither the sphere's vertical offset nor the full model's
    # heading is pinned any more, and the sphere would leave 12° of heading error: refused, naming why.
    sim = _generic_sensor(400, 0.03, 12.0)
    with pytest.raises(CalibrationError, match="the sphere model: the samples do not determine"):
        magfit.fit(sim.samples, "auto")


# ---------------------------------------------------------------------- restricted models against the full one


@pytest.mark.parametrize(
    "soft_iron",
    [np.diag([1.25, 1.0, 0.75]), [[1.0, 0.25, 0.0], [0.25, 1.0, 0.0], [0.0, 0.0, 1.0]],
     [[1.0, 0.0, 0.25], [0.0, 1.0, 0.0], [0.25, 0.0, 1.0]]],
    ids=["scales", "xy", "xz"],
)  # fmt: skip
@pytest.mark.parametrize("method", ["sphere", "diag", "minmax"])
def test_a_restricted_model_on_half_a_sphere_with_soft_iron_is_refused_or_says_what_it_misses(
    method: str, soft_iron: list[list[float]]
) -> None:
    # Half a sphere of directions with ±25 % soft iron: the sphere moves its centre to absorb the soft iron and
    # leaves a few per cent, under the old fixed 2.5 % of the field (before: "supported", 18° of heading error).
    # The F test against the full ellipsoid on the same samples sees it: refused, or weak with the heading it
    # may cost counted in the stated one-sigma.
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from _common import heading_error_deg
    from campaign import hemisphere_attitudes

    matrix = np.asarray(soft_iron, dtype=float)
    attitudes = hemisphere_attitudes(2000, np.random.default_rng(1))
    sim = magfit.simulate(
        2000, soft_iron=matrix, hard_iron=[0.3, -0.2, 0.1], noise=0.005, orientations=attitudes, seed=1
    )
    forced = magfit.fit(sim.samples, method, allow_undetermined=True)
    support = forced.support
    if method == "diag" and np.count_nonzero(matrix - np.diag(np.diag(matrix))) == 0:
        assert "model_inadequate" not in support.codes  # axis-aligned soft iron is diag's own model
    else:
        assert "model_inadequate" in support.codes, support
    if support.verdict != "refused":
        stated = forced.diagnostics.uncertainty.heading_sigma_deg  # type: ignore[union-attr]
        assert heading_error_deg(forced, sim) <= max(3.0 * stated, 0.1), (heading_error_deg(forced, sim), stated)
