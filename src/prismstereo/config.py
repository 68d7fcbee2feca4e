"""Rig configuration: frozen dataclasses for the camera and the prism, loaded from TOML and validated.

The TOML layout is documented in docs/rig.md. Validation happens here, before any image is read, and every
problem is reported as a :class:`~prismstereo.errors.ConfigError` that says what was expected.
"""

from __future__ import annotations

import math
import os
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from prismstereo.errors import ConfigError
from prismstereo.io.atomic import atomic_write_text


def _number(section: str, key: str, value: Any, *, integer: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        kind = "an integer" if integer else "a number"
        raise ConfigError(f"[{section}] {key}: expected {kind}, got {value!r}")
    if integer and not float(value).is_integer():
        raise ConfigError(f"[{section}] {key}: expected an integer, got {value!r}")
    if not math.isfinite(float(value)):
        raise ConfigError(f"[{section}] {key}: expected a finite number, got {value!r}")
    return float(value)


def _positive(section: str, key: str, value: Any, *, integer: bool = False) -> float:
    v = _number(section, key, value, integer=integer)
    if v <= 0:
        raise ConfigError(f"[{section}] {key}: expected a positive value, got {value!r}")
    return v


def _vector(
    section: str, key: str, value: Any, *, lengths: tuple[int, ...], limit: float, names: str
) -> tuple[float, ...]:
    """A short list of finite numbers, each within ±limit (a sanity range for physical rigs)."""
    if not isinstance(value, list | tuple) or len(value) not in lengths:
        raise ConfigError(f"[{section}] {key}: expected {names}, got {value!r}")
    out = tuple(_number(section, key, v) for v in value)
    for v in out:
        if abs(v) > limit:
            raise ConfigError(f"[{section}] {key}: expected every value within ±{limit:g}, got {list(value)!r}")
    return out


def _check_keys(section: str, table: Mapping[str, Any], required: set[str], optional: set[str]) -> None:
    if not isinstance(table, Mapping):
        raise ConfigError(f"[{section}]: expected a table, got {table!r}")
    missing = sorted(required - set(table))
    if missing:
        raise ConfigError(f"[{section}]: missing key(s) {', '.join(missing)}; add them to the rig file")
    unknown = sorted(set(table) - required - optional)
    if unknown:
        known = ", ".join(sorted(required | optional))
        raise ConfigError(f"[{section}]: unknown key(s) {', '.join(unknown)}; expected only {known}")


@dataclass(frozen=True)
class CameraSpec:
    """The real camera: a pinhole with optional OpenCV lens distortion (docs/rig.md).

    Attributes
    ----------
    width, height : int
        Sensor size in pixels.
    focal_length : float or None
        Focal length in mm (with ``pixel_size``; may be omitted when ``fx`` and ``fy`` are given).
    pixel_size : float or None
        Pixel pitch in mm (square pixels).
    principal_point : tuple of float or None
        (cx, cy) in pixels; ``None`` means the image centre ((width-1)/2, (height-1)/2).
    fx, fy : float or None
        Focal lengths in pixels (from a calibration); when given they define K instead of
        focal_length / pixel_size. Both or neither.
    distortion : (k1, k2, p1, p2, k3)
        OpenCV distortion of normalised coordinates; all zero = a distortion-free pinhole. A real pixel
        looks along the ray through its undistorted normalised point (as ``cv2.undistortPoints``).
    f_number, focus_distance : float or None
        The lens's f-number N and the distance it is focused at (mm from the optical centre along the
        axis), both or neither. With them the depth pipeline and the self-calibration leave out the band
        around the image of each prism edge where a pixel's beam passes through two faces and the views
        mix (``prismstereo.optics.lens.apex_band_mask``, width f_px · (f/N) · |1/apex − 1/F| px).
    """

    width: int
    height: int
    focal_length: float | None = None
    pixel_size: float | None = None
    principal_point: tuple[float, float] | None = None
    fx: float | None = None
    fy: float | None = None
    distortion: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)
    f_number: float | None = None
    focus_distance: float | None = None

    def __post_init__(self) -> None:
        _positive("camera", "width", self.width, integer=True)
        if (self.f_number is None) != (self.focus_distance is None):
            raise ConfigError(f"[camera] f_number, focus_distance: expected both or neither (the apex band's "
                              f"width needs both), got f_number={self.f_number!r}, "
                              f"focus_distance={self.focus_distance!r}")
        if self.f_number is not None and self.focus_distance is not None:
            object.__setattr__(self, "f_number", _positive("camera", "f_number", self.f_number))
            object.__setattr__(self, "focus_distance", _positive("camera", "focus_distance", self.focus_distance))
            if self.focal_length is None and self.pixel_size is None:
                raise ConfigError("[camera] f_number: expected focal_length or pixel_size (mm) beside it, to size "
                                  "the aperture; add one to the rig file")
        _positive("camera", "height", self.height, integer=True)
        if (self.fx is None) != (self.fy is None):
            raise ConfigError(f"[camera] fx, fy: expected both or neither, got fx={self.fx!r}, fy={self.fy!r}")
        if self.fx is None and (self.focal_length is None or self.pixel_size is None):
            raise ConfigError("[camera]: expected focal_length and pixel_size, or fx and fy (px), got neither; "
                              "add them to the rig file")
        if self.focal_length is not None:
            _positive("camera", "focal_length", self.focal_length)
        if self.pixel_size is not None:
            _positive("camera", "pixel_size", self.pixel_size)
        if self.fx is not None and self.fy is not None:
            object.__setattr__(self, "fx", _positive("camera", "fx", self.fx))
            object.__setattr__(self, "fy", _positive("camera", "fy", self.fy))
        dist = _vector("camera", "distortion", self.distortion, lengths=(4, 5), limit=100.0,
                       names="[k1, k2, p1, p2, k3] (OpenCV order)")
        for name, v in zip(("p1", "p2"), dist[2:4], strict=True):
            if abs(v) > 1.0:
                raise ConfigError(f"[camera] distortion: expected tangential {name} within ±1, got {v!r}")
        object.__setattr__(self, "distortion", tuple(dist) + (0.0,) * (5 - len(dist)))
        if self.principal_point is not None:
            pp = self.principal_point
            if not isinstance(pp, list | tuple) or len(pp) != 2:
                raise ConfigError(f"[camera] principal_point: expected [cx, cy], got {pp!r}")
            for v in pp:
                _number("camera", "principal_point", v)
            object.__setattr__(self, "principal_point", (float(pp[0]), float(pp[1])))
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    @property
    def focal_px(self) -> float:
        """Focal length in pixels: f / pixel_size, or the mean of fx and fy when those are given."""
        if self.fx is not None and self.fy is not None:
            return 0.5 * (self.fx + self.fy)
        assert self.focal_length is not None and self.pixel_size is not None  # __post_init__ checked
        return self.focal_length / self.pixel_size

    @property
    def focal_xy(self) -> tuple[float, float]:
        """(fx, fy) in pixels."""
        if self.fx is not None and self.fy is not None:
            return (self.fx, self.fy)
        f = self.focal_px
        return (f, f)

    @property
    def has_distortion(self) -> bool:
        """True when any distortion coefficient is non-zero."""
        return any(v != 0.0 for v in self.distortion)

    @property
    def center(self) -> tuple[float, float]:
        """Principal point (cx, cy) in pixels."""
        if self.principal_point is not None:
            return self.principal_point
        return ((self.width - 1) / 2.0, (self.height - 1) / 2.0)

    @property
    def K(self) -> np.ndarray:
        """3×3 intrinsic matrix of the real camera."""
        cx, cy = self.center
        fx, fy = self.focal_xy
        return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return (self.width, self.height)


@dataclass(frozen=True)
class PrismSpec:
    """An N-face pyramid prism with its apex toward the camera (docs/rig.md).

    Attributes
    ----------
    faces : int
        Number of lateral faces: 2 = bi-prism, 3 = tri-prism, N ≥ 4 = N-face pyramid.
    corner_angle : float
        Inclination of every lateral face to the back plane, degrees, in (0, 90).
    refractive_index : float
        Index of the glass (> 1); the surrounding medium is air (index 1).
    apex_distance : float
        Optical centre to apex along +Z, mm.
    back_distance : float
        Optical centre to the back plane along +Z, mm (> apex_distance).
    height : float or None
        Apex to the base of the faces, mm; ``None`` = back_distance − apex_distance. A smaller height
        leaves a flat slab (parallel plate) behind the faces.
    rotation : float
        Rotation of the face layout about the optical axis, degrees.
    tilt : (tx, ty)
        Tilt of the prism about the camera's X axis, then its Y axis, through the apex, degrees.
    decenter : (dx, dy)
        Offset of the apex from the optical axis, mm.

    Notes
    -----
    Pose (docs/rig.md): a point p of the nominal prism maps to the camera frame as
    ``Ry(ty)·Rx(tx)·Rz(rotation)·(p − A0) + A0 + (dx, dy, 0)``, A0 = (0, 0, apex_distance). The rotation is
    carried by the face directions; tilt and decenter by :meth:`pose`.
    """

    faces: int
    corner_angle: float
    refractive_index: float
    apex_distance: float
    back_distance: float
    height: float | None = None
    rotation: float = 0.0
    tilt: tuple[float, float] = (0.0, 0.0)
    decenter: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        faces = _number("prism", "faces", self.faces, integer=True)
        if faces < 2:
            raise ConfigError(f"[prism] faces: expected an integer >= 2 (2 = bi-prism), got {self.faces!r}")
        angle = _number("prism", "corner_angle", self.corner_angle)
        if not 0.0 < angle < 90.0:
            raise ConfigError(f"[prism] corner_angle: expected degrees in (0, 90), got {self.corner_angle!r}")
        n = _number("prism", "refractive_index", self.refractive_index)
        if n <= 1.0:
            raise ConfigError(f"[prism] refractive_index: expected a value > 1 (glass), got {n!r}")
        apex = _positive("prism", "apex_distance", self.apex_distance)
        back = _positive("prism", "back_distance", self.back_distance)
        if back <= apex:
            raise ConfigError(
                f"[prism] back_distance: expected the back plane behind the apex (> apex_distance = {apex}), "
                f"got {back}"
            )
        if self.height is not None:
            h = _positive("prism", "height", self.height)
            if h > back - apex + 1e-9:
                raise ConfigError(
                    f"[prism] height: expected at most back_distance - apex_distance = {back - apex:g} mm, "
                    f"got {h:g}"
                )
        _number("prism", "rotation", self.rotation)
        tilt = _vector("prism", "tilt", self.tilt, lengths=(2,), limit=30.0, names="[tx, ty] in degrees")
        decenter = _vector("prism", "decenter", self.decenter, lengths=(2,), limit=apex,
                           names="[dx, dy] in mm")
        object.__setattr__(self, "tilt", (tilt[0], tilt[1]))
        object.__setattr__(self, "decenter", (decenter[0], decenter[1]))
        object.__setattr__(self, "faces", int(faces))

    @property
    def is_posed(self) -> bool:
        """True when the prism is tilted or decentred (the rotation alone keeps it on the axis)."""
        return any(v != 0.0 for v in self.tilt + self.decenter)

    def pose(self) -> tuple[np.ndarray, np.ndarray]:
        """(M, A): the prism's tilt Ry(ty)·Rx(tx) (3, 3) and its apex (3,) in the camera frame, so that a point
        q of the centred prism (with its rotation) is at ``M (q − A0) + A`` (docs/rig.md)."""
        tx, ty = (math.radians(v) for v in self.tilt)
        cx, sx, cy, sy = math.cos(tx), math.sin(tx), math.cos(ty), math.sin(ty)
        rx = np.array([[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]])
        ry = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
        apex = np.array([self.decenter[0], self.decenter[1], self.apex_distance])
        return ry @ rx, apex

    @property
    def face_height(self) -> float:
        """Apex to the base of the faces, mm."""
        return self.back_distance - self.apex_distance if self.height is None else float(self.height)

    @property
    def tan_alpha(self) -> float:
        return math.tan(math.radians(self.corner_angle))

    @property
    def inradius(self) -> float:
        """Distance from the axis to each face's base edge, mm: the prism's lateral half-width."""
        return self.face_height / self.tan_alpha

    def face_directions(self) -> np.ndarray:
        """N×3 unit vectors u_k = (cos θ_k, sin θ_k, 0), θ_k = rotation + 360°·k/N (docs/rig.md)."""
        theta = np.radians(self.rotation + 360.0 * np.arange(self.faces) / self.faces)
        return np.stack([np.cos(theta), np.sin(theta), np.zeros_like(theta)], axis=1)

    def face_normals(self) -> np.ndarray:
        """N×3 unit normals of the lateral faces, pointing out of the glass (toward the camera, −Z)."""
        u = self.face_directions()
        n = np.concatenate([self.tan_alpha * u[:, :2], -np.ones((self.faces, 1))], axis=1)
        return n / np.linalg.norm(n, axis=1, keepdims=True)


@dataclass(frozen=True)
class Rig:
    """A camera with a prism in front of it."""

    camera: CameraSpec
    prism: PrismSpec
    name: str = field(default="rig", compare=False)

    @property
    def n_views(self) -> int:
        return self.prism.faces

    def view_name(self, face: int) -> str:
        """Human name of the virtual camera created by ``face`` ("left"/"right" for a bi-prism)."""
        # a calibrated bi-prism is rotated by a degree or two and still has a left and a right view
        if self.prism.faces == 2 and abs((self.prism.rotation + 180.0) % 360.0 - 180.0) < 10.0:
            return "right" if face == 0 else "left"
        return f"view{face}"

    def to_dict(self) -> dict[str, Any]:
        cam: dict[str, Any] = {"width": self.camera.width, "height": self.camera.height}
        if self.camera.focal_length is not None:
            cam["focal_length"] = self.camera.focal_length
        if self.camera.pixel_size is not None:
            cam["pixel_size"] = self.camera.pixel_size
        if self.camera.principal_point is not None:
            cam["principal_point"] = list(self.camera.principal_point)
        if self.camera.fx is not None:
            cam["fx"] = self.camera.fx
            cam["fy"] = self.camera.fy
        if self.camera.has_distortion:
            cam["distortion"] = list(self.camera.distortion)
        if self.camera.f_number is not None:
            cam["f_number"] = self.camera.f_number
            cam["focus_distance"] = self.camera.focus_distance
        prism: dict[str, Any] = {
            "faces": self.prism.faces,
            "corner_angle": self.prism.corner_angle,
            "refractive_index": self.prism.refractive_index,
            "apex_distance": self.prism.apex_distance,
            "back_distance": self.prism.back_distance,
        }
        if self.prism.height is not None:
            prism["height"] = self.prism.height
        if self.prism.rotation != 0.0:
            prism["rotation"] = self.prism.rotation
        if any(self.prism.tilt):
            prism["tilt"] = list(self.prism.tilt)
        if any(self.prism.decenter):
            prism["decenter"] = list(self.prism.decenter)
        return {"camera": cam, "prism": prism}

    def to_toml(self) -> str:
        return tomli_w.dumps(self.to_dict())

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write the rig as TOML, atomically."""
        atomic_write_text(path, self.to_toml())

    def with_prism(self, **changes: Any) -> Rig:
        """A copy with some prism parameters changed (validated again)."""
        return replace(self, prism=replace(self.prism, **changes))


_CAMERA_REQUIRED = {"width", "height"}
_CAMERA_OPTIONAL = {"principal_point", "focal_length", "pixel_size", "fx", "fy", "distortion", "f_number",
                    "focus_distance"}
_PRISM_REQUIRED = {"faces", "corner_angle", "refractive_index", "apex_distance", "back_distance"}
_PRISM_OPTIONAL = {"height", "rotation", "tilt", "decenter"}


def rig_from_dict(data: Mapping[str, Any], *, name: str = "rig", extra_sections: set[str] | None = None) -> Rig:
    """Build and validate a :class:`Rig` from the parsed TOML mapping of docs/rig.md.

    ``extra_sections`` names top-level tables that may appear beside [camera] and [prism] (a scene file
    carries its own), which are then ignored here.
    """
    allowed = {"camera", "prism"} | (extra_sections or set())
    unknown = sorted(set(data) - allowed)
    if unknown:
        raise ConfigError(f"rig: unknown table(s) {', '.join(unknown)}; expected [camera] and [prism]")
    for section in ("camera", "prism"):
        if section not in data:
            raise ConfigError(f"rig: missing table [{section}]; see docs/rig.md for the rig layout")
    cam = data["camera"]
    _check_keys("camera", cam, _CAMERA_REQUIRED, _CAMERA_OPTIONAL)
    prism = data["prism"]
    _check_keys("prism", prism, _PRISM_REQUIRED, _PRISM_OPTIONAL)
    pp = cam.get("principal_point")
    camera = CameraSpec(
        width=cam["width"],
        height=cam["height"],
        focal_length=cam.get("focal_length"),
        pixel_size=cam.get("pixel_size"),
        principal_point=tuple(pp) if isinstance(pp, list) else pp,
        fx=cam.get("fx"),
        fy=cam.get("fy"),
        distortion=cam.get("distortion", (0.0, 0.0, 0.0, 0.0, 0.0)),
        f_number=cam.get("f_number"),
        focus_distance=cam.get("focus_distance"),
    )
    spec = PrismSpec(
        faces=prism["faces"],
        corner_angle=prism["corner_angle"],
        refractive_index=prism["refractive_index"],
        apex_distance=prism["apex_distance"],
        back_distance=prism["back_distance"],
        height=prism.get("height"),
        rotation=prism.get("rotation", 0.0),
        tilt=prism.get("tilt", (0.0, 0.0)),
        decenter=prism.get("decenter", (0.0, 0.0)),
    )
    return Rig(camera=camera, prism=spec, name=name)


def read_toml(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Parse a TOML file, turning I/O and syntax problems into :class:`ConfigError`."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"expected a TOML file, got {str(p)!r} (no such file)")
    try:
        with p.open("rb") as fh:
            return tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"expected valid TOML in {str(p)!r}, got a syntax error: {exc}") from None


def load_rig(path: str | os.PathLike[str], *, extra_sections: set[str] | None = None) -> Rig:
    """Load and validate a rig TOML file (docs/rig.md)."""
    return rig_from_dict(read_toml(path), name=Path(path).stem, extra_sections=extra_sections)


#: World depths searched when nothing narrows them (mm): the thesis's experiments lie within (§7.3)
DEFAULT_DEPTH_RANGE_MM: tuple[float, float] = (800.0, 5000.0)

#: The thesis's camera (Table 3.2): 1024×768 px of 4.65 µm behind a 25 mm lens
THESIS_CAMERA = CameraSpec(width=1024, height=768, focal_length=25.0, pixel_size=0.00465)
#: The thesis's glass (n) and the distance of the prism's apex from the camera centre (mm, Table 3.2)
THESIS_REFRACTIVE_INDEX = 1.5
THESIS_APEX_DISTANCE_MM = 210.0


def thesis_biprism(corner_angle: float = 6.4) -> Rig:
    """The thesis's bi-prism rig (Table 3.2): 1024×768, 4.65 µm, f = 25 mm, n = 1.5, apex 210, back 215.6."""
    return Rig(
        camera=THESIS_CAMERA,
        prism=PrismSpec(
            faces=2, corner_angle=corner_angle, refractive_index=THESIS_REFRACTIVE_INDEX,
            apex_distance=THESIS_APEX_DISTANCE_MM, back_distance=215.6
        ),
        name=f"thesis-biprism-{corner_angle:g}",
    )


def thesis_triprism() -> Rig:
    """The thesis's tri-prism rig (§4.3): h = 4 mm, t = 6.8 mm, r = 37.3 mm, n = 1.5, apex 210 mm."""
    h, t, r, n_faces = 4.0, 6.8, 37.3, 3
    alpha = math.degrees(math.atan(h / (r * math.cos(math.pi / n_faces))))
    return Rig(
        camera=THESIS_CAMERA,
        prism=PrismSpec(
            faces=n_faces,
            corner_angle=alpha,
            refractive_index=THESIS_REFRACTIVE_INDEX,
            apex_distance=THESIS_APEX_DISTANCE_MM,
            back_distance=THESIS_APEX_DISTANCE_MM + h + t,
            height=h,
        ),
        name="thesis-triprism",
    )


def pyramid_rig(faces: int = 4, *, corner_angle: float = 12.1, rotation: float = 0.0) -> Rig:
    """An N-face pyramid prism rig on the thesis camera, built like the tri-prism (h = 4, t = 6.8 mm)."""
    return Rig(
        camera=THESIS_CAMERA,
        prism=PrismSpec(
            faces=faces,
            corner_angle=corner_angle,
            refractive_index=THESIS_REFRACTIVE_INDEX,
            apex_distance=THESIS_APEX_DISTANCE_MM,
            back_distance=220.8,
            height=4.0,
            rotation=rotation,
        ),
        name=f"pyramid-{faces}",
    )
