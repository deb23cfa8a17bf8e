import numpy as np
import pytest
from pydantic import ValidationError

from rangeseg_o3d import registry
from rangeseg_o3d.fitting import Cylinder, FitFailure, Plane, Sphere, fit_primitive
from rangeseg_o3d.fitting.classify import PLUGIN, PrimitiveFitterConfig, bind_sensor
from rangeseg_o3d.sensor import NoiseModel, Sensor

NOISE = 0.005  # LMS200 range noise


def test_clean_and_noisy_planes_are_planes(synth):
    rng = np.random.default_rng(0)
    for noise in (0.0, NOISE):
        model = fit_primitive(synth.plane(rng, (0.2, 0.1, 1), 2.0, n=400, noise=noise))
        assert isinstance(model, Plane)
        assert model.inliers == 400


@pytest.mark.parametrize("axis", [(1, 0, 0), (0, 0, 1), (0.4, 0.3, 0.2)])
def test_half_cylinder_is_cylinder(synth, axis):
    rng = np.random.default_rng(1)
    pts, _ = synth.cylinder(rng, axis, (0, 1, 2), 0.15, n=400, arc=np.radians(150), length=0.6, noise=NOISE)
    model = fit_primitive(pts)
    assert isinstance(model, Cylinder), model
    assert model.radius == pytest.approx(0.15, abs=0.01)


def test_sphere_cap_is_sphere(synth):
    rng = np.random.default_rng(2)
    pts, _ = synth.sphere(rng, (0, 0.5, 2.5), 0.2, n=400, cap=np.radians(150), noise=NOISE)
    model = fit_primitive(pts)
    assert isinstance(model, Sphere), model
    assert model.radius == pytest.approx(0.2, abs=0.01)


def test_gently_curved_cylinder_within_plane_rms_is_still_a_cylinder(synth):
    # r = 1 m over 40 deg: sagitta 6 cm, plane rms under plane_rms = 0.03; the
    # curvature test must still send it to the cylinder.
    rng = np.random.default_rng(3)
    pts, _ = synth.cylinder(rng, (0, 0, 1), (0, 0, 0), 1.0, n=600, arc=np.radians(40), length=1.0, noise=0.002)
    model = fit_primitive(pts, plane_rms=0.03)
    assert isinstance(model, Cylinder), model
    assert model.radius == pytest.approx(1.0, abs=0.02)


@pytest.mark.parametrize("seed", range(8))
def test_noisy_planes_never_become_spheres_or_cylinders(synth, seed):
    # plane noise above plane_rms: it must come back unfitted, not as a huge curved model
    rng = np.random.default_rng(seed)
    pts = synth.plane(rng, rng.normal(size=3), 2.0, n=300, size=1.5, noise=0.015)
    model = fit_primitive(pts)
    assert isinstance(model, FitFailure), model
    assert "plane rms" in model.reason


def test_thin_arc_of_huge_cylinder_refused_by_min_arc(synth):
    rng = np.random.default_rng(4)
    pts, _ = synth.cylinder(rng, (0, 0, 1), (0, 0, 0), 4.0, n=400, arc=np.radians(20), length=1.0, noise=NOISE)
    model = fit_primitive(pts, plane_rms=0.005, max_radius=10.0)
    assert not isinstance(model, Cylinder)
    if isinstance(model, FitFailure):
        assert "arc" in model.reason or "rms" in model.reason


def test_max_radius_refuses_big_cylinder(synth):
    rng = np.random.default_rng(5)
    pts, _ = synth.cylinder(rng, (0, 0, 1), (0, 0, 0), 2.0, n=400, arc=np.radians(90), length=1.0, noise=0.001)
    assert isinstance(fit_primitive(pts), Cylinder)
    refused = fit_primitive(pts, max_radius=1.0)
    assert isinstance(refused, FitFailure) and "max_radius" in refused.reason


def test_random_blob_is_unfitted_with_reasons():
    model = fit_primitive(np.random.default_rng(6).normal(size=(200, 3)))
    assert isinstance(model, FitFailure) and model.kind == "primitive"
    assert "plane rms" in model.reason and "cylinder" in model.reason and "sphere" in model.reason


def test_range_dependent_threshold(synth):
    # RGB-D-like noise 1.425e-3 z^2 at z = 3 m is ~13 mm: plane only with the range term
    rng = np.random.default_rng(7)
    pts = synth.plane(rng, (0, 0, 1), 3.0, n=400, size=1.0, noise=0.0128)
    assert not fit_primitive(pts)
    assert isinstance(fit_primitive(pts, plane_rms=0.005, rms_per_range2=2 * 1.425e-3), Plane)


def test_too_few_and_invalid_points():
    assert "at least 10" in fit_primitive(np.random.default_rng(0).normal(size=(9, 3))).reason
    assert "NaN" in fit_primitive(np.full((20, 3), np.nan)).reason
    line = np.outer(np.arange(20.0), [1, 0, 0])
    assert "collinear" in fit_primitive(line).reason
    with pytest.raises(ValueError):
        fit_primitive(np.zeros((20, 2)))


def test_config_fields_are_exactly_the_keywords():
    import inspect

    # range_growth stands for rms_per_range2, which follows from the sensor (bind_sensor),
    # as noise_floor does (no field: the sensor's sigma0); resolve_bends is asked per call
    # (the refinement's last decision of a pixel grid's planes), no setting
    keywords = [
        name for name, p in inspect.signature(fit_primitive).parameters.items()
        if p.kind is p.KEYWORD_ONLY and name != "resolve_bends"
    ]
    fields = list(PrimitiveFitterConfig.model_fields)
    assert fields == [("range_growth" if k == "rms_per_range2" else k) for k in keywords if k != "noise_floor"]
    defaults = PrimitiveFitterConfig()
    for name in keywords:
        if name not in ("rms_per_range2", "noise_floor"):
            assert getattr(defaults, name) == inspect.signature(fit_primitive).parameters[name].default
    quadratic = Sensor(NoiseModel(sigma0=0.001, sigma_quadratic=0.002))
    bound = bind_sensor(PrimitiveFitterConfig(range_growth=1.5).model_dump(), quadratic)
    assert sorted(bound) == sorted(keywords)
    assert bound["rms_per_range2"] == pytest.approx(0.003, rel=1e-12)
    assert bind_sensor(defaults.model_dump(), Sensor())["rms_per_range2"] == 0.0


@pytest.mark.parametrize(
    "field, value",
    [("plane_rms", 0), ("plane_rms", -0.01), ("max_radius", float("inf")), ("curvature_gain", 0.5), ("bogus", 1)],
)
def test_config_rejects_bad_values_naming_the_field(field, value):
    with pytest.raises(ValidationError, match=field):
        PrimitiveFitterConfig(**{field: value})


def test_plugin_registered_and_runs_with_config(synth):
    plugin = registry.get("fitter", "primitives")
    assert plugin is PLUGIN and plugin.config is PrimitiveFitterConfig
    rng = np.random.default_rng(8)
    params = bind_sensor(PrimitiveFitterConfig(plane_rms=0.02).model_dump(), Sensor())
    assert isinstance(plugin.run(synth.plane(rng, (0, 0, 1), 1.0, noise=0.01), **params), Plane)


def test_quadric_shape_tells_cylinders_from_spheres(synth):
    from rangeseg_o3d.fitting import fit_plane
    from rangeseg_o3d.fitting.classify import quadric_shape

    rng = np.random.default_rng(9)
    cyl, _ = synth.cylinder(rng, (0.3, 0.2, 1), (0, 0, 2), 0.3, n=400, arc=np.radians(120), noise=0.002)
    sph, _ = synth.sphere(rng, (0, 0, 2), 0.3, n=400, cap=np.radians(120), noise=0.002)
    flat = synth.plane(rng, (0, 0, 1), 2.0, n=400, noise=0.002)
    gain, roundness = quadric_shape(cyl, fit_plane(cyl))
    assert gain > 3 and roundness < 0.35
    gain, roundness = quadric_shape(sph, fit_plane(sph))
    assert gain > 3 and roundness > 0.65
    gain, _ = quadric_shape(flat, fit_plane(flat))
    assert gain < 1.1


def test_refit_keeps_the_kind_and_judges_it(synth):
    from rangeseg_o3d.fitting.classify import refit_primitive

    rng = np.random.default_rng(10)
    pts, _ = synth.cylinder(rng, (1, 0, 0), (0, 0, 2), 0.25, n=400, arc=np.radians(140), noise=NOISE)
    first = fit_primitive(pts[:200])
    assert isinstance(first, Cylinder)
    again = PLUGIN.refit(pts, first)
    assert isinstance(again, Cylinder) and again.radius == pytest.approx(0.25, abs=0.01)
    # the same points refitted as a plane break the plane threshold: a reasoned failure
    flat = fit_primitive(synth.plane(rng, (0, 0, 1), 2.0, noise=NOISE))
    refused = refit_primitive(pts, flat)
    assert isinstance(refused, FitFailure) and "plane rms" in refused.reason
    # and a noisy plane refitted as a cylinder is refused too
    assert not refit_primitive(synth.plane(rng, (0, 0, 1), 2.0, noise=NOISE), first)
    with pytest.raises(TypeError):
        refit_primitive(pts, "cylinder")


def test_non_finite_points_are_counted_on_every_path(synth):
    # the compiled preparation finds them; the message counts them, for each kind refitted
    from rangeseg_o3d.fitting.classify import refit_primitive

    rng = np.random.default_rng(11)
    pts, _ = synth.cylinder(rng, (1, 0, 0), (0, 0, 2), 0.25, n=200, arc=np.radians(140), noise=NOISE)
    flat = synth.plane(rng, (0, 0, 1), 2.0, n=200, noise=NOISE)
    cylinder, plane = fit_primitive(pts), fit_primitive(flat)
    assert isinstance(cylinder, Cylinder) and isinstance(plane, Plane)
    bad, bad_flat = pts.copy(), flat.copy()
    bad[[3, 50, 199], [0, 2, 1]] = bad_flat[[3, 50, 199], [0, 2, 1]] = [np.nan, np.inf, -np.inf]
    for refused, kind in [(fit_primitive(bad), "primitive"), (refit_primitive(bad, cylinder), "cylinder"),
                          (refit_primitive(bad_flat, plane), "plane")]:
        assert isinstance(refused, FitFailure) and refused.kind == kind
        assert "3 of 200 points are NaN or infinite" in refused.reason
