"""prismstereo.design.verify: the measured disparity error explains the measured depth error (small sensor)."""

from __future__ import annotations

import numpy as np
import pytest

from prismstereo.config import CameraSpec, Rig, thesis_biprism
from prismstereo.design import measure_at_depth, verify, verify_scene
from prismstereo.design.verify import AGREEMENT
from prismstereo.errors import ConfigError

CAM = CameraSpec(width=320, height=240, focal_length=25.0, pixel_size=0.00465 * 1024 / 320)


def test_verify_scene_texture_scales_with_depth() -> None:
    rig = Rig(camera=CAM, prism=thesis_biprism().prism)
    a = verify_scene(rig, 1000.0).objects[0].texture
    b = verify_scene(rig, 2000.0).objects[0].texture
    assert b.scale == pytest.approx(2 * a.scale)
    assert verify_scene(rig, 1000.0, abbe=64.17).abbe == 64.17


@pytest.mark.slow
def test_measured_disparity_error_explains_the_depth_error() -> None:
    rig = Rig(camera=CAM, prism=thesis_biprism().prism)
    (row,) = verify(rig, depths=[1500.0], preset="fast", depth_range=(1200.0, 1800.0))
    m = row.measured
    assert m.coverage > 0.8 and m.n_points > 5000
    assert 0.0 < m.median_abs_disparity_px < 0.2
    assert abs(m.model_ratio - 1.0) < 0.1  # |δd| × sensitivity = the depth error, pixel by pixel
    assert np.isfinite(row.ratio) and row.agrees == (abs(row.ratio - 1) <= AGREEMENT)
    assert row.to_dict()["measured_rel"] == m.median_rel


def test_measure_rejects_unknown_preset() -> None:
    with pytest.raises(ConfigError, match="preset"):
        measure_at_depth(Rig(camera=CAM, prism=thesis_biprism().prism), 1500.0, preset="quick")
