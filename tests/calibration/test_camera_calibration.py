from __future__ import annotations

import cv2
import numpy as np
import pytest

from prismstereo.calibration import Board, calibrate_camera
from prismstereo.errors import ImageError


def test_calibration_recovers_the_intrinsics(camera_photos, small_true):
    names = [f"p{i}" for i in range(len(camera_photos))]
    photos = list(camera_photos)
    photos[3] = cv2.GaussianBlur(photos[3], (0, 0), 5.0)  # a blurred photo is rejected, not used
    res = calibrate_camera(photos, Board(8, 6, 5.0), names=names)
    assert "p3" in res.rejected and "p3" not in res.per_view_rms
    cam, true = res.camera, small_true.camera
    assert res.rms_px < 0.2
    assert abs(cam.fx / true.focal_px - 1) < 0.01 and abs(cam.fy / true.focal_px - 1) < 0.01
    # over a narrow field (±5.5° here) the principal point trades against the board rotations: it is
    # only loosely determined (OpenCV's own std says so)
    dc = np.hypot(cam.center[0] - true.center[0], cam.center[1] - true.center[1])
    assert dc < 3.0 * np.hypot(res.std["cx"], res.std["cy"]) + 1.0
    # the fit explains the corners to noise level in every used photo
    assert max(res.per_view_rms.values()) < 0.3


def test_too_few_good_views_is_a_clear_error(camera_photos):
    with pytest.raises(ImageError, match=r"expected at least 5 photos with a whole, sharp 8x6 board, got 3 of 3"):
        calibrate_camera(camera_photos[:3], Board(8, 6, 5.0))
    with pytest.raises(ImageError, match="expected photos of one size"):
        calibrate_camera([camera_photos[0], camera_photos[1][:100]], Board(8, 6, 5.0))
