"""Self-calibration from an ordinary capture, and the drift check, on a small (512×384) misaligned rig."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from prismstereo.calibration.drift import row_misalignment
from prismstereo.calibration.from_scene import calibrate_from_scene, parse_scene_free
from prismstereo.cli import main
from prismstereo.errors import ConfigError, ImageError
from prismstereo.io import write_image


def _planes(noise_scale: float = 1.0, solid: bool = False):
    from prismstereo.simulate import NoiseTexture, Plane, Rectangle, Scene, SolidTexture

    def tex(scale: float, seed: int):
        return SolidTexture(color=(0.5, 0.5, 0.5)) if solid else NoiseTexture(scale=scale * noise_scale, seed=seed)

    return Scene(objects=(
        Plane(center=(0.0, 0.0, 1800.0), rotation=(0.0, 15.0, 0.0), texture=tex(30.0, 1), name="wall"),
        Rectangle(center=(-30.0, -40.0, 1300.0), size=(120.0, 90.0), rotation=(10.0, -25.0, 0.0),
                  texture=tex(20.0, 2), name="a"),
        Rectangle(center=(30.0, 50.0, 1100.0), size=(110.0, 80.0), rotation=(-15.0, 20.0, 0.0),
                  texture=tex(15.0, 3), name="b"),
    ), supersample=2, noise=1.0, vignetting=0.2, seed=5, name="planes")


@pytest.fixture(scope="module")
def start_rig(small_true):
    """The true camera (calibrated lens) with the nominal, centred prism."""
    return small_true.with_prism(rotation=0.0, tilt=(0.0, 0.0), decenter=(0.0, 0.0))


@pytest.fixture(scope="module")
def scene_capture(small_true):
    from prismstereo.simulate import render_capture

    return render_capture(small_true, _planes()).image


def test_self_calibration_recovers_rotation_and_tilt(start_rig, small_true, scene_capture):
    cal = calibrate_from_scene(start_rig, [scene_capture])
    assert cal.n_matches >= 200
    assert abs(cal.estimates["rotation"] - 1.4) < 0.05
    assert abs(cal.estimates["tilt_x"] - 1.0) < 0.15
    assert cal.observed["rotation"] and cal.observed["tilt_x"]
    assert cal.residual_before["p95"] > 3.0 and cal.residual_after["p95"] < 0.3
    # the refined rig rectifies the capture's rows as well as the true one; the nominal one does not
    nominal = row_misalignment(start_rig, scene_capture)
    refined = row_misalignment(cal.rig, scene_capture)
    assert nominal.needs_recalibration and nominal.p95_px > 4.0
    assert not refined.needs_recalibration and refined.p95_px < 0.5
    # the library's verdict names the library's call, not the command's flags
    assert "from_scene=True" in nominal.summary() and "--" not in nominal.summary()


def test_self_calibration_refuses_a_textureless_scene(small_true, start_rig):
    from prismstereo.simulate import render_capture

    flat = render_capture(small_true, _planes(solid=True)).image
    with pytest.raises(ImageError, match="too little texture"):
        calibrate_from_scene(start_rig, [flat])


def test_scene_free_refuses_the_scale_parameters():
    assert parse_scene_free("rotation,tilt") == ("rotation", "tilt_x", "tilt_y")
    with pytest.raises(ConfigError, match="depth scale"):
        parse_scene_free("rotation,refractive_index")


def test_check_and_calibrate_from_scene_commands(tmp_path, start_rig, small_true, scene_capture, capsys):
    cap = tmp_path / "capture.png"
    write_image(cap, scene_capture)
    nominal_path, true_path = tmp_path / "nominal.toml", tmp_path / "true.toml"
    start_rig.save(nominal_path)
    small_true.save(true_path)
    report = tmp_path / "check.json"
    assert main(["check", str(nominal_path), str(cap), "-o", str(report)]) == 3
    data = json.loads(report.read_text())
    assert data["needs_recalibration"] is True and data["p95_dy_px"] > 4.0
    assert "calibrate-prism RIG CAPTURE --from-scene" in capsys.readouterr().out  # the command's words
    assert main(["check", str(true_path), str(cap)]) == 0
    assert "no recalibration needed" in capsys.readouterr().out

    out = tmp_path / "refined.toml"
    assert main(["calibrate-prism", str(nominal_path), str(cap), "--from-scene", "-o", str(out)]) == 0
    assert out.exists() and (tmp_path / "refined.report.json").exists()
    assert main(["check", str(out), str(cap)]) == 0
    # refusals: one line, exit 2, nothing written
    bad = tmp_path / "bad.toml"
    assert main(["calibrate-prism", str(nominal_path), str(cap), "--from-scene", "--free", "apex_distance",
                 "-o", str(bad)]) == 2
    flat = tmp_path / "flat.png"
    write_image(flat, np.full_like(scene_capture, 128))
    assert main(["calibrate-prism", str(nominal_path), str(flat), "--from-scene", "-o", str(bad)]) == 2
    assert main(["check", str(nominal_path), str(flat)]) == 2
    assert not bad.exists()
    err = capsys.readouterr().err.strip().splitlines()
    assert err and all(line.startswith("prismstereo ") for line in err)


def test_scene_calibration_keeps_the_depth_scale(start_rig, scene_capture):
    cal = calibrate_from_scene(start_rig, [scene_capture], free="rotation")
    p0, p1 = start_rig.prism, cal.rig.prism
    assert (p1.apex_distance, p1.refractive_index, p1.corner_angle) == (p0.apex_distance, p0.refractive_index,
                                                                          p0.corner_angle)
    assert dataclasses.asdict(cal.rig.camera) == dataclasses.asdict(start_rig.camera)


def test_depth_self_calibrate(tmp_path, start_rig, scene_capture, capsys):
    cap = tmp_path / "capture.png"
    write_image(cap, scene_capture)
    rig_path = tmp_path / "nominal.toml"
    start_rig.save(rig_path)
    out = tmp_path / "out"
    assert main(["depth", str(rig_path), str(cap), "-o", str(out), "--method", "sgm", "--no-refine",
                 "--self-calibrate"]) == 0
    run = json.loads((out / "run.json").read_text())
    sc = run["self_calibration"]
    assert abs(sc["estimates"]["rotation"] - 1.4) < 0.05 and sc["n_matches"] >= 200
    unobserved = sc["depth_error_unobserved"]
    assert set(unobserved["parameters"]) == {k for k, seen in sc["observed"].items() if not seen}
    assert isinstance(sc["warnings"], list)
    # the held tilt y of this capture can move the depth by > 0.2 %: the run's own warnings say so too
    assert sc["warnings"] and set(sc["warnings"]) <= set(run["warnings"])
    refined = (out / "rig_refined.toml").read_text()
    assert "rotation" in refined and "self-calibration" in capsys.readouterr().out


def test_the_depth_error_of_unobserved_parameters_is_quantified(start_rig, scene_capture):
    from prismstereo.calibration.prism import prism_values, with_prism_values
    from prismstereo.calibration.scene_uncertainty import _depths, uncertainty_warnings, unobserved_depth_error

    cal = calibrate_from_scene(start_rig, [scene_capture])
    rep = unobserved_depth_error(cal)
    lo, mid, hi = rep["depth_mm"]
    assert 1000.0 < lo <= mid <= hi < 2000.0  # the planes at 1.1-1.8 m
    unobserved = {k for k, seen in cal.observed.items() if not seen}
    assert set(rep["parameters"]) == unobserved
    for k, v in rep["parameters"].items():
        assert v["std"] == cal.std[k] and 0.0 < v["median_pct"] <= v["p95_pct"]
        assert abs(v["per_unit_pct"] * v["std"] - v["median_pct"]) < 1e-3
    assert rep["max_median_pct"] == max((v["median_pct"] for v in rep["parameters"].values()), default=0.0)
    # the input value may be off either way, and the depth change is not odd in it: the worse way is stated
    z0 = _depths(cal.rig, cal)
    for k, v in rep["parameters"].items():
        for sign in (1.0, -1.0):
            values = prism_values(cal.rig)
            values[k] += sign * cal.std[k]
            z1 = _depths(with_prism_values(cal.rig, values), cal)
            ok = np.isfinite(z0) & np.isfinite(z1)
            assert v["median_pct"] >= float(np.median(100.0 * np.abs(z1[ok] - z0[ok]) / z0[ok])) - 1e-3
    assert uncertainty_warnings(rep, limit_pct=1e9) == []
    if rep["parameters"]:
        lines = uncertainty_warnings(rep, limit_pct=0.0)
        assert len(lines) == len(rep["parameters"]) and all("not observed" in line for line in lines)


def test_dense_matches_are_correspondences_of_the_capture(start_rig, small_true, scene_capture):
    """Optical-flow matches found in the nominal rig's warp are the true rig's correspondences: their rays
    through the true prism meet (sub-pixel), through the nominal one they do not."""
    from prismstereo.calibration.dense import dense_pair_matches
    from prismstereo.calibration.from_scene import ray_residuals
    from prismstereo.optics import rays_from_pixels

    pa, pb = dense_pair_matches(scene_capture, start_rig, faces=(0, 1))
    assert pa.shape[0] >= 100 and pa.shape == pb.shape
    cam = small_true.camera
    da, db = rays_from_pixels(pa, cam.K, cam.distortion), rays_from_pixels(pb, cam.K, cam.distortion)
    n = pa.shape[0]
    faces = (np.zeros(n, dtype=int), np.ones(n, dtype=int))
    true_r, _ = ray_residuals(small_true, da, db, *faces)
    nominal_r, _ = ray_residuals(start_rig, da, db, *faces)
    assert np.nanmedian(np.abs(true_r)) < 0.2 and np.nanmedian(np.abs(nominal_r)) > 2.0
    with pytest.raises(ConfigError, match="faces"):
        dense_pair_matches(scene_capture, start_rig, faces=(1, 1))


def test_an_unobserved_parameter_is_held_at_its_input_value(start_rig, small_true, scene_capture):
    from prismstereo.calibration.from_scene import PRIOR_STD

    cal = calibrate_from_scene(start_rig, [scene_capture], free="rotation,tilt,decenter", dense="never")
    held = [k for k, seen in cal.observed.items() if not seen]
    assert "decenter_x" in held and tuple(held) == cal.held  # the decenter moves rays by < 0.05 px per mm
    for k in held:
        assert cal.estimates[k] == cal.initial[k] and cal.std[k] == PRIOR_STD[k]
        assert any(n.startswith(f"{k}: not observed") and "held at" in n for n in cal.notes)
    assert abs(cal.estimates["rotation"] - 1.4) < 0.05
    assert cal.report()["held"] == list(held)
    with pytest.raises(ConfigError, match="dense"):
        calibrate_from_scene(start_rig, [scene_capture], dense="sometimes")
