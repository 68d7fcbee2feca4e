"""prismstereo.design: glasses, the glass sizing, the prediction, the search's checks and its errors."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from prismstereo.cameras import thesis_camera
from prismstereo.config import THESIS_CAMERA, CameraSpec, PrismSpec, Rig, thesis_biprism
from prismstereo.design import (
    DISPARITY_PRECISION,
    GLASSES,
    Request,
    assess,
    parse_glass,
    parse_glasses,
    predict,
    search,
    size_prism,
)
from prismstereo.design.search import _balanced_decenter, _candidate
from prismstereo.errors import ConfigError, GeometryError
from prismstereo.optics import trace_pixels

N15 = parse_glass("n=1.5")


def test_glass_table_and_parsing() -> None:
    assert GLASSES["N-BK7"].n_d == 1.5168 and GLASSES["N-BK7"].abbe == 64.17
    assert parse_glass("fused silica").n_d == 1.4585
    assert parse_glass("pmma").abbe == 57.2
    assert parse_glass("Polycarbonate").n_d == 1.585
    g = parse_glass("n=1.62")
    assert g.n_d == 1.62 and g.abbe is None
    assert [x.name for x in parse_glasses("N-BK7,PMMA")] == ["N-BK7", "PMMA"]
    with pytest.raises(ConfigError, match="glass: expected one of"):
        parse_glass("unobtainium")
    with pytest.raises(ConfigError, match="n=<index>"):
        parse_glass("n=abc")
    with pytest.raises(ConfigError, match="refractive index"):
        parse_glass("n=0.9")


def test_precision_table_is_measured() -> None:
    """Every preset has a measured, positive disparity precision well below a pixel."""
    assert {"fast", "balanced"} <= set(DISPARITY_PRECISION) <= {"fast", "balanced", "accurate"}
    assert all(0.0 < v < 0.5 for v in DISPARITY_PRECISION.values())


def test_predict_thesis_biprism() -> None:
    rig = thesis_biprism()
    p = predict(rig, depths=[1200.0, 1500.0, 1800.0], disparity_precision=0.02)
    base = float(np.linalg.norm(thesis_camera(rig, 0).C - thesis_camera(rig, 1).C))
    assert p.views == (1, 0)
    for d in p.depths:
        assert d.baseline_mm == pytest.approx(base, rel=0.01)
        # d = f B / z with z close to the depth beyond the virtual centres
        assert d.disparity_px == pytest.approx(rig.camera.focal_px * base / d.depth_mm, rel=0.03)
        assert d.relative_error == pytest.approx(d.depth_mm * 0.02 / (rig.camera.focal_px * base), rel=0.03)
        assert 0.5 < d.field_share <= 1.0
    errs = [d.relative_error for d in p.depths]
    assert errs == sorted(errs)
    # linear in the precision
    p2 = predict(rig, depths=[1500.0], disparity_precision=0.04)
    assert p2.depths[0].relative_error == pytest.approx(2 * p.at(1500.0).relative_error, rel=1e-9)
    assert [s.width_px for s in p.sub_images] == [512.0, 512.0]
    assert p.glass.across_flats == pytest.approx(2 * rig.prism.inradius)
    assert p.lost_share == 0.0
    with pytest.raises(ConfigError, match="depths"):
        predict(rig, depths=[100.0])
    with pytest.raises(ConfigError, match="disparity_precision"):
        predict(rig, depths=[1500.0], disparity_precision="slow")


@settings(max_examples=12, deadline=None)
@given(alpha=st.floats(2.0, 20.0), apex=st.floats(60.0, 350.0), n=st.sampled_from([1.4585, 1.5, 1.5168, 1.585]),
       faces=st.sampled_from([2, 3, 4]))
def test_sized_glass_covers_the_field(alpha: float, apex: float, n: float, faces: int) -> None:
    """The glass of size_prism lets every sensor pixel's ray through (bounded tracing), with its margin."""
    cam = CameraSpec(width=320, height=240, focal_length=25.0, pixel_size=0.00465 * 1024 / 320)
    prism, tir = size_prism(cam, faces=faces, corner_angle=alpha, refractive_index=n, apex_distance=apex)
    assert prism is not None and tir == 0.0
    u, v = np.meshgrid(np.linspace(0, cam.width - 1, 41), np.linspace(0, cam.height - 1, 31))
    b = trace_pixels(Rig(camera=cam, prism=prism), np.stack([u, v], -1))
    assert b.valid.all()
    # not much larger than needed: half the margin less would still be enough, a fifth of the size less is not
    smaller = PrismSpec(faces=faces, corner_angle=alpha, refractive_index=n, apex_distance=apex,
                        back_distance=prism.back_distance - 0.2 * prism.face_height, height=0.8 * prism.face_height)
    assert not trace_pixels(Rig(camera=cam, prism=smaller), np.stack([u, v], -1)).valid.all()


def _req(**kw: object) -> Request:
    args: dict = {"camera": THESIS_CAMERA, "near": 1200.0, "far": 1800.0, "glasses": (N15,), "precision": 0.02}
    args.update(kw)
    return Request(**args)


def test_tir_rejection() -> None:
    """Beyond ~83° (n = 1.5) the rays reach the back plane past the critical angle (part of the field, then all)."""
    prism, tir = size_prism(THESIS_CAMERA, faces=2, corner_angle=83.25, refractive_index=1.5, apex_distance=210.0)
    assert prism is None and 0.0 < tir < 1.0
    (c,) = _candidate(_req(), 2, 83.25, 210.0, N15, 16.0)
    assert c.rejected == "tir" and "totally internally reflected" in c.reason
    (c,) = _candidate(_req(), 2, 85.0, 210.0, N15, 16.0)
    assert c.rejected == "tir" and "axial ray" in c.reason
    given_prism = PrismSpec(faces=2, corner_angle=83.25, refractive_index=1.5, apex_distance=210.0,
                            back_distance=2000.0)
    assert assess(_req(), given_prism).rejected == "tir"


def test_no_overlap_rejection() -> None:
    """A 20° bi-prism's views cross near 300 mm: at 1.2-1.8 m they share nothing."""
    (c,) = _candidate(_req(), 2, 20.0, 210.0, N15, 16.0)
    assert c.rejected == "overlap"
    assert c.prediction is not None and c.prediction.min_field_share < 0.05
    assert "share" in c.reason and "min_field_share" in c.reason


def test_glass_that_does_not_fit() -> None:
    (c,) = _candidate(_req(max_size=30.0), 2, 6.4, 210.0, N15, 16.0)
    assert c.rejected == "size" and "max_size 30" in c.reason
    small = PrismSpec(faces=2, corner_angle=6.4, refractive_index=1.5, apex_distance=210.0, back_distance=211.0)
    c = assess(_req(), small)
    assert c.rejected == "size" and "does not cover the field" in c.reason


def test_balanced_triprism_has_equal_sub_images() -> None:
    dec = _balanced_decenter(_req(faces=(3,)), 3, 12.1, N15, 210.0)
    assert dec[0] < 0  # toward the single face's side's opposite: face 0's sub-image widens
    prism, _ = size_prism(THESIS_CAMERA, faces=3, corner_angle=12.1, refractive_index=1.5, apex_distance=120.0,
                          decenter=_balanced_decenter(_req(faces=(3,)), 3, 12.1, N15, 120.0))
    assert prism is not None
    p = predict(Rig(camera=THESIS_CAMERA, prism=prism), depths=[1500.0], disparity_precision=0.02)
    assert p.width_spread <= 0.10
    centred = predict(Rig(camera=THESIS_CAMERA, prism=replace_decenter(prism)), depths=[1500.0],
                      disparity_precision=0.02)
    assert centred.width_spread > 0.3  # the thesis's complaint


def replace_decenter(prism: PrismSpec) -> PrismSpec:
    return PrismSpec(faces=prism.faces, corner_angle=prism.corner_angle, refractive_index=prism.refractive_index,
                     apex_distance=prism.apex_distance, back_distance=prism.back_distance, height=prism.height)


@pytest.fixture(scope="module")
def thesis_design():
    rig = thesis_biprism()
    return rig, search(rig.camera, near=1200.0, far=1800.0, faces=(2,), glass="n=1.5", include=(rig.prism,),
                       disparity_precision=0.02)


def test_thesis_prism_is_a_candidate(thesis_design) -> None:
    rig, design = thesis_design
    given_c = [c for c in design.candidates if c.source == "given"]
    assert len(given_c) == 1 and given_c[0].feasible and given_c[0].rank is not None
    # the searched grid holds the thesis's own shape too (its glass sized to the field)
    near = [c for c in design.feasible if c.source == "search" and abs(c.corner_angle - 6.5) < 0.01
            and abs(c.apex_distance - 210) < 25]
    assert near, "a 6.5° bi-prism near 210 mm should meet the request"
    best = design.best
    assert best.rank == 1
    assert best.error_at(1800.0) <= given_c[0].error_at(1800.0)
    assert best.prediction is not None and best.prediction.min_field_share >= 0.5
    ranks = [c.rank for c in design.feasible]
    assert ranks == list(range(1, len(ranks) + 1))
    errs = [c.prediction.worst_error for c in design.feasible]
    assert errs == sorted(errs)
    assert all(c.rejected in ("tir", "size", "overlap", "field", "balance", "accuracy")
               for c in design.candidates if not c.feasible)
    d = design.to_dict()
    assert d["n_candidates"] == len(design.candidates) and d["best"]["prediction"]["per_depth"]


def test_no_solution_names_the_binding_constraint() -> None:
    cam = CameraSpec(width=320, height=240, focal_length=25.0, pixel_size=0.00465 * 1024 / 320)
    with pytest.raises(GeometryError, match=r"max_size 5 mm binds.*raise max_size") as e:
        search(cam, near=1200.0, far=1800.0, max_size=5.0)
    assert "\n" not in str(e.value)
    with pytest.raises(GeometryError, match=r"accuracy 1e-05 % at 1800 mm binds.*the best reaches"):
        search(cam, near=1200.0, far=1800.0, accuracy=1e-7, max_apex_distance=120.0, disparity_precision=0.02)
    with pytest.raises(GeometryError,
                       match=r"field 5000 × 5000 mm at 1800 mm binds.*the largest common field at 1800 mm is"):
        search(cam, near=1200.0, far=1800.0, field=(5000.0, 5000.0), max_apex_distance=120.0)


@pytest.mark.parametrize(("kw", "match"), [
    ({"near": 1800.0, "far": 1200.0}, "near, far"),
    ({"accuracy": 2.0}, "accuracy"),
    ({"faces": (1,)}, "faces"),
    ({"max_size": -1.0}, "max_size"),
    ({"min_apex_distance": 1500.0}, "min_apex_distance"),
    ({"field": (0.0, 10.0)}, "field"),
    ({"min_field_share": 1.5}, "min_field_share"),
])
def test_request_validation(kw: dict, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        _req(**kw)


def test_request_errors_from_search() -> None:
    with pytest.raises(ConfigError, match="glass"):
        search(THESIS_CAMERA, near=1200.0, far=1800.0, glass="glass-of-water")
    with pytest.raises(ConfigError, match="disparity_precision"):
        search(THESIS_CAMERA, near=1200.0, far=1800.0, disparity_precision=-1.0)


def test_corner_angle_of_size_prism_is_checked() -> None:
    with pytest.raises(ConfigError, match="corner_angle"):
        size_prism(THESIS_CAMERA, faces=2, corner_angle=95.0, refractive_index=1.5, apex_distance=210.0)
    with pytest.raises(ConfigError, match="edge_thickness"):
        size_prism(THESIS_CAMERA, faces=2, corner_angle=5.0, refractive_index=1.5, apex_distance=210.0,
                   edge_thickness=-1.0)
    assert math.isfinite(THESIS_CAMERA.focal_px)
