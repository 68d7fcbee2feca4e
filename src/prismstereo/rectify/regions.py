"""Sub-image split: which part of the real image each prism face sees (thesis §3.1, §4.1.1).

The region of face k is traced, not assumed: every real pixel's ray is traced through the prism
(:func:`~prismstereo.optics.face_map`) and the pixels entering through face k form its region. The band
along the prism's edges (the apex edges between faces and the prism's outer border) is out of focus in a
real capture — the camera focuses on the scene, the edges are 210 mm away — and mixes two views, so
each region is eroded by ``margin_px``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np

from prismstereo.config import Rig
from prismstereo.errors import GeometryError, ImageError
from prismstereo.optics import face_map

log = logging.getLogger(__name__)

#: default width (px) of the band dropped along the prism edges
MARGIN_PX = 4


@dataclass(frozen=True)
class ViewRegion:
    """The part of the real image that sees through one face.

    Attributes
    ----------
    face : int
        Face index.
    name : str
        View name (``rig.view_name(face)``).
    mask : (H, W) bool
        Real pixels that see through ``face``, at least ``margin_px`` away from the region's border.
    bbox : (x0, y0, x1, y1) ints
        Bounding box of ``mask``, end-exclusive: ``mask[y0:y1, x0:x1]`` holds every True pixel.
    """

    face: int
    name: str
    mask: np.ndarray
    bbox: tuple[int, int, int, int]

    @property
    def offset(self) -> tuple[int, int]:
        """(x0, y0): the real-image pixel of the crop's (0, 0)."""
        return self.bbox[0], self.bbox[1]

    @property
    def area(self) -> int:
        return int(self.mask.sum())


@dataclass(frozen=True)
class SubImage:
    """One face's crop of a capture: ``image[r, c]`` is the real pixel (c + offset[0], r + offset[1])."""

    face: int
    name: str
    image: np.ndarray
    mask: np.ndarray
    offset: tuple[int, int]


def _erode(mask: np.ndarray, margin_px: int) -> np.ndarray:
    if margin_px <= 0:
        return mask
    # The border of the sensor is not a prism edge, so pad with True before eroding.
    k = 2 * int(margin_px) + 1
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))
    padded = cv2.copyMakeBorder(mask.astype(np.uint8), margin_px, margin_px, margin_px, margin_px,
                                cv2.BORDER_REPLICATE)
    eroded = cv2.erode(padded, kernel)[margin_px:-margin_px, margin_px:-margin_px]
    return eroded.astype(bool)


def view_regions(rig: Rig, *, margin_px: int = MARGIN_PX) -> list[ViewRegion]:
    """The region of the real image seen through each face (thesis §3.1 "two halves", §4.1.1 "three
    sub-images"), traced exactly and eroded by ``margin_px`` along the prism edges.

    Parameters
    ----------
    rig : Rig
    margin_px : int
        Width of the band dropped along every edge between a face's region and anything else (another
        face, or pixels that see no glass). The sensor border is kept.

    Returns
    -------
    list of ViewRegion, one per face, in face order.

    Raises
    ------
    GeometryError
        If a face is not seen by any pixel after the margin is dropped.
    """
    if margin_px < 0:
        raise GeometryError(f"expected margin_px >= 0, got {margin_px}")
    faces = face_map(rig)
    out = []
    for k in range(rig.prism.faces):
        mask = _erode(faces == k, int(margin_px))
        ys, xs = np.nonzero(mask)
        if ys.size == 0:
            raise GeometryError(f"expected face {k} to be seen by some real pixels with a {margin_px} px margin, "
                                f"got none")
        bbox = (int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1)
        out.append(ViewRegion(face=k, name=rig.view_name(k), mask=mask, bbox=bbox))
    return out


def check_image_size(image: np.ndarray, rig: Rig) -> None:
    """Raise :class:`ImageError` unless ``image`` is H×W or H×W×C with the rig's sensor size."""
    shape = np.shape(image)
    if len(shape) not in (2, 3) or shape[:2] != (rig.camera.height, rig.camera.width):
        got = f"{shape[1]}×{shape[0]}" if len(shape) >= 2 else f"shape {shape}"
        raise ImageError(f"expected an image of the rig's sensor size {rig.camera.width}×{rig.camera.height}, "
                         f"got {got}")


def split_capture(
    image: np.ndarray, rig: Rig, *, margin_px: int = MARGIN_PX, regions: list[ViewRegion] | None = None,
    fill: float = 0,
) -> list[SubImage]:
    """Cut a capture into the sub-images of its faces.

    Parameters
    ----------
    image : (H, W) or (H, W, C) array
        The real capture, H×W the rig's sensor size.
    rig : Rig
    margin_px : int
        See :func:`view_regions` (ignored when ``regions`` is given).
    regions : list of ViewRegion, optional
        Precomputed regions.
    fill : float
        Value given to pixels of a crop that do not belong to the face.

    Returns
    -------
    list of SubImage, one per face: the bounding-box crop, its mask, its offset in the real image.
    """
    check_image_size(image, rig)
    regions = view_regions(rig, margin_px=margin_px) if regions is None else regions
    img = np.asarray(image)
    out = []
    for r in regions:
        x0, y0, x1, y1 = r.bbox
        crop = img[y0:y1, x0:x1].copy()
        m = r.mask[y0:y1, x0:x1]
        crop[~m] = fill
        out.append(SubImage(face=r.face, name=r.name, image=crop, mask=m.copy(), offset=(x0, y0)))
    return out
