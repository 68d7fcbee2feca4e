"""Small rigs and scenes for fast simulator tests."""

from __future__ import annotations

import pytest

from prismstereo.config import CameraSpec, PrismSpec, Rig


@pytest.fixture(scope="session")
def small_biprism() -> Rig:
    """The thesis bi-prism on a 256×192 sensor with 4× larger pixels (same field of view)."""
    return Rig(
        camera=CameraSpec(width=256, height=192, focal_length=25.0, pixel_size=0.0186),
        prism=PrismSpec(faces=2, corner_angle=6.4, refractive_index=1.5, apex_distance=210.0, back_distance=215.6),
        name="small-biprism",
    )


@pytest.fixture(scope="session")
def small_triprism() -> Rig:
    return Rig(
        camera=CameraSpec(width=192, height=144, focal_length=25.0, pixel_size=0.0248),
        prism=PrismSpec(faces=3, corner_angle=12.1053, refractive_index=1.5, apex_distance=210.0,
                        back_distance=220.8, height=4.0),
        name="small-triprism",
    )
