"""Scene model for the prism-capture simulator: textured primitives in the world frame (mm).

Every object has a pose (centre + rotation), a size, and a texture mapped in the object's own surface
coordinates (s, t) in mm:

* :class:`Rectangle` — a flat panel. In its local frame it lies in the XY plane, faces −Z (toward the
  camera at identity rotation); s runs along local +X from the left edge, t along local +Y (down, as image
  rows) from the top edge, so an image texture appears upright and unmirrored when seen from the front.
* :class:`Box` — six rectangles; each face has its own (s, t) from one of its corners and a different
  ``salt`` so procedural textures differ from face to face.
* :class:`Sphere` — s = R·(longitude + π) with longitude 0 toward local −Z, t = R·colatitude from the
  local −Y pole (the top).
* :class:`Plane` — an infinite plane (e.g. a background wall); s, t measured from its centre.
* :class:`RGBDSurface` — a photographed scene: a colour image and its depth map as a triangulated height
  field over the source camera's pixel grid, its colour the photograph (no separate texture).

Rotations are given as extrinsic XYZ Euler angles in degrees (``R = Rz·Ry·Rx``, local-to-world), or built
from a facing normal with :func:`rotation_from_normal`.

Textures: :class:`SolidTexture`, :class:`CheckerTexture` (exact square edges, optional finite board with
white margin), :class:`NoiseTexture` (seeded multi-octave colour value noise) and :class:`ImageTexture`.
Colours are RGB floats in [0, 1].
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from prismstereo.errors import ConfigError

Vec3 = tuple[float, float, float]
Color = tuple[float, float, float]

_IDENTITY: Vec3 = (0.0, 0.0, 0.0)


# --------------------------------------------------------------------------- validation helpers
def _vec(obj: object, name: str, n: int, *, positive: bool = False, lo: float | None = None,
         hi: float | None = None) -> None:
    """Check attribute ``name`` of a frozen dataclass is n finite numbers; store it as a float tuple."""
    v = getattr(obj, name)
    what = f"{type(obj).__name__} {name}"
    try:
        t = tuple(float(x) for x in v)
    except (TypeError, ValueError):
        raise ConfigError(f"{what}: expected {n} numbers, got {v!r}") from None
    if len(t) != n or not all(math.isfinite(x) for x in t):
        raise ConfigError(f"{what}: expected {n} finite numbers, got {v!r}")
    if positive and not all(x > 0 for x in t):
        raise ConfigError(f"{what}: expected {n} positive numbers, got {v!r}")
    if (lo is not None and min(t) < lo) or (hi is not None and max(t) > hi):
        raise ConfigError(f"{what}: expected values in [{lo}, {hi}], got {v!r}")
    object.__setattr__(obj, name, t)


def _scalar(obj: object, name: str, *, positive: bool = False, lo: float | None = None,
            hi: float | None = None) -> None:
    v = getattr(obj, name)
    what = f"{type(obj).__name__} {name}"
    if isinstance(v, bool) or not isinstance(v, int | float | np.integer | np.floating) or not math.isfinite(v):
        raise ConfigError(f"{what}: expected a finite number, got {v!r}")
    if (positive and v <= 0) or (lo is not None and v < lo) or (hi is not None and v > hi):
        rng = "a positive number" if positive else f"a number in [{lo}, {hi}]"
        raise ConfigError(f"{what}: expected {rng}, got {v!r}")


# --------------------------------------------------------------------------- rotations
def euler_to_matrix(rotation: Vec3 | np.ndarray) -> np.ndarray:
    """Local-to-world rotation matrix from extrinsic XYZ Euler angles in degrees.

    Parameters
    ----------
    rotation : (3,) (rx, ry, rz), degrees; ``R = Rz(rz) · Ry(ry) · Rx(rx)``.

    Returns
    -------
    (3, 3) float64 rotation matrix; its columns are the object's local axes in the world.
    """
    return np.asarray(Rotation.from_euler("xyz", np.asarray(rotation, dtype=np.float64), degrees=True).as_matrix())


def matrix_to_euler(matrix: np.ndarray) -> Vec3:
    """Inverse of :func:`euler_to_matrix`: (3, 3) rotation → (rx, ry, rz) degrees."""
    e = Rotation.from_matrix(np.asarray(matrix, dtype=np.float64)).as_euler("xyz", degrees=True)
    return (float(e[0]), float(e[1]), float(e[2]))


def rotation_from_normal(normal: Vec3 | np.ndarray, *, spin: float = 0.0) -> Vec3:
    """Euler angles (degrees) that turn a rectangle so its front faces along ``normal``.

    The front of a rectangle faces local −Z; its texture's t axis (image rows) is kept as close as possible
    to world +Y (down), or world +Z when the normal is vertical; ``spin`` (degrees) then turns the surface
    about the normal.

    Parameters
    ----------
    normal : (3,) direction the front face looks toward (e.g. (0, 0, −1) = at the camera).
    spin : float, degrees.

    Returns
    -------
    (rx, ry, rz) Euler angles in degrees for :func:`euler_to_matrix`.
    """
    n = np.asarray(normal, dtype=np.float64)
    norm = float(np.linalg.norm(n))
    if not math.isfinite(norm) or norm < 1e-12:
        raise ConfigError(f"normal: expected a non-zero finite 3-vector, got {list(map(float, n))}")
    e3 = -n / norm
    down = np.array([0.0, 1.0, 0.0])
    if abs(float(e3 @ down)) > 0.999:
        down = np.array([0.0, 0.0, 1.0])
    e2 = down - (down @ e3) * e3
    e2 /= np.linalg.norm(e2)
    e1 = np.cross(e2, e3)
    R = np.stack([e1, e2, e3], axis=1)
    if spin:
        R = R @ euler_to_matrix((0.0, 0.0, spin))
    return matrix_to_euler(R)


# --------------------------------------------------------------------------- textures
@dataclass(frozen=True)
class SolidTexture:
    """A uniform colour."""

    color: Color = (0.5, 0.5, 0.5)

    def __post_init__(self) -> None:
        _vec(self, "color", 3, lo=0.0, hi=1.0)


@dataclass(frozen=True)
class CheckerTexture:
    """A checkerboard with exact square edges.

    Attributes
    ----------
    square : float
        Square side, mm.
    colors : pair of RGB
        Colour of square (0, 0) (the one touching the pattern's origin) and of its neighbours.
    squares : (nx, ny) or None
        Finite board of nx × ny squares whose top-left corner is at (margin, margin) in the surface's
        (s, t); outside it the surface has ``border_color``. ``None`` tiles the whole surface.
        The board's inner corners (OpenCV's pattern size (nx − 1, ny − 1)) are at
        (margin + i·square, margin + j·square), i = 1 … nx − 1, j = 1 … ny − 1.
    margin : float
        Offset of the pattern from the surface's (s, t) origin, mm.
    border_color : RGB
    """

    square: float = 20.0
    colors: tuple[Color, Color] = ((0.0, 0.0, 0.0), (1.0, 1.0, 1.0))
    squares: tuple[int, int] | None = None
    margin: float = 0.0
    border_color: Color = (1.0, 1.0, 1.0)

    def __post_init__(self) -> None:
        _scalar(self, "square", positive=True)
        _scalar(self, "margin", lo=0.0, hi=math.inf)
        _vec(self, "border_color", 3, lo=0.0, hi=1.0)
        if len(self.colors) != 2:
            raise ConfigError(f"CheckerTexture colors: expected two RGB colours, got {self.colors!r}")
        for c in self.colors:
            if len(c) != 3 or not all(0.0 <= float(x) <= 1.0 for x in c):
                raise ConfigError(f"CheckerTexture colors: expected RGB values in [0, 1], got {self.colors!r}")
        object.__setattr__(self, "colors", tuple(tuple(float(x) for x in c) for c in self.colors))
        if self.squares is not None:
            if len(self.squares) != 2 or min(int(q) for q in self.squares) < 1:
                raise ConfigError(f"CheckerTexture squares: expected (nx, ny) >= 1, got {self.squares!r}")
            object.__setattr__(self, "squares", (int(self.squares[0]), int(self.squares[1])))


@dataclass(frozen=True)
class NoiseTexture:
    """Seeded multi-octave colour value noise: strong texture at several scales, for stereo matching.

    Each RGB channel is an independent fractal sum of ``octaves`` value-noise layers; layer k has feature
    size ``scale / 2**k`` mm and weight ``persistence**k``; the sum is stretched by ``contrast`` about 0.5
    and clipped to [0, 1].

    Attributes
    ----------
    scale : float
        Feature size of the coarsest octave, mm.
    octaves : int
    persistence : float
        Weight ratio between successive octaves, in (0, 1].
    contrast : float
    seed : int
    """

    scale: float = 50.0
    octaves: int = 6
    persistence: float = 0.8
    contrast: float = 2.5
    seed: int = 0

    def __post_init__(self) -> None:
        _scalar(self, "scale", positive=True)
        _scalar(self, "persistence", lo=0.0, hi=1.0)
        _scalar(self, "contrast", positive=True)
        if not 1 <= int(self.octaves) <= 16 or int(self.octaves) != self.octaves:
            raise ConfigError(f"NoiseTexture octaves: expected an integer in 1..16, got {self.octaves!r}")
        if int(self.seed) != self.seed or self.seed < 0:
            raise ConfigError(f"NoiseTexture seed: expected a non-negative integer, got {self.seed!r}")


@dataclass(frozen=True)
class ImageTexture:
    """An RGB image mapped onto the surface.

    Attributes
    ----------
    path : str
        Where the image came from (kept for the resolved scene file); may be empty for in-memory images.
    image : (H, W, 3) uint8 or float array
        The pixels (uint8 are scaled to [0, 1]).
    size : (w, h) or None
        Size of one copy of the image on the surface, mm; it repeats beyond. ``None`` stretches it over
        each face (required for planes, which have no extent).
    """

    path: str = ""
    image: np.ndarray = field(default_factory=lambda: np.zeros((1, 1, 3)), compare=False, repr=False)
    size: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        img = np.asarray(self.image)
        if img.ndim not in (2, 3) or img.size == 0 or (img.ndim == 3 and img.shape[2] < 3):
            raise ConfigError(f"ImageTexture image: expected an H×W×3 (or H×W) array, got shape {img.shape}")
        if self.size is not None:
            _vec(self, "size", 2, positive=True)

    def as_float(self) -> np.ndarray:
        """(H, W, 3) float32 RGB in [0, 1]."""
        img = np.asarray(self.image)
        if img.ndim == 2:
            img = np.repeat(img[:, :, None], 3, axis=2)
        if img.dtype == np.uint8:
            return (img[:, :, :3].astype(np.float32) / np.float32(255.0)).copy()
        if img.dtype == np.uint16:
            return (img[:, :, :3].astype(np.float32) / np.float32(65535.0)).copy()
        return np.clip(img[:, :, :3].astype(np.float32), 0.0, 1.0)


Texture = SolidTexture | CheckerTexture | NoiseTexture | ImageTexture


# --------------------------------------------------------------------------- objects
@dataclass(frozen=True)
class _Posed:
    center: Vec3
    rotation: Vec3

    def __post_init__(self) -> None:
        _vec(self, "center", 3)
        _vec(self, "rotation", 3)
        if isinstance(self, Rectangle):
            _vec(self, "size", 2, positive=True)
        elif isinstance(self, Box):
            _vec(self, "size", 3, positive=True)
        elif isinstance(self, Sphere):
            _scalar(self, "radius", positive=True)

    @property
    def matrix(self) -> np.ndarray:
        """(3, 3) local-to-world rotation; columns are the local axes."""
        return euler_to_matrix(self.rotation)

    def to_world(self, local: np.ndarray) -> np.ndarray:
        """Local points (..., 3) in mm → world points (..., 3)."""
        return np.asarray(local, dtype=np.float64) @ self.matrix.T + np.asarray(self.center, dtype=np.float64)


@dataclass(frozen=True)
class Rectangle(_Posed):
    """A textured flat rectangle of ``size`` = (width, height) mm centred at ``center``.

    The surface coordinates of a world point p are ``(s, t) = (R[:,0]·(p − c) + w/2, R[:,1]·(p − c) + h/2)``.
    """

    center: Vec3 = (0.0, 0.0, 1000.0)
    size: tuple[float, float] = (100.0, 100.0)
    rotation: Vec3 = _IDENTITY
    texture: Texture = field(default_factory=NoiseTexture)
    name: str = ""

    def surface_to_world(self, st: np.ndarray) -> np.ndarray:
        """Surface coordinates (..., 2) in mm → world points (..., 3) on the rectangle's plane."""
        st = np.asarray(st, dtype=np.float64)
        local = np.stack(
            [st[..., 0] - self.size[0] / 2.0, st[..., 1] - self.size[1] / 2.0, np.zeros(st.shape[:-1])], axis=-1
        )
        return self.to_world(local)

    @property
    def normal(self) -> np.ndarray:
        """(3,) unit normal of the front face (local −Z in the world)."""
        return -self.matrix[:, 2]


@dataclass(frozen=True)
class Box(_Posed):
    """A box of ``size`` = (sx, sy, sz) mm along its local axes, centred at ``center``."""

    center: Vec3 = (0.0, 0.0, 1000.0)
    size: Vec3 = (100.0, 100.0, 100.0)
    rotation: Vec3 = _IDENTITY
    texture: Texture = field(default_factory=NoiseTexture)
    name: str = ""


@dataclass(frozen=True)
class Sphere(_Posed):
    """A sphere of ``radius`` mm."""

    center: Vec3 = (0.0, 0.0, 1000.0)
    radius: float = 50.0
    rotation: Vec3 = _IDENTITY
    texture: Texture = field(default_factory=NoiseTexture)
    name: str = ""


@dataclass(frozen=True)
class Plane(_Posed):
    """An infinite plane through ``center`` facing local −Z (e.g. a background wall)."""

    center: Vec3 = (0.0, 0.0, 3000.0)
    rotation: Vec3 = _IDENTITY
    texture: Texture = field(default_factory=NoiseTexture)
    name: str = ""


@dataclass(frozen=True)
class RGBDSurface:
    """A photographed scene: a colour image and its depth map, rendered as a triangulated height field.

    The source camera is a pinhole with focal lengths ``focal`` = (fx, fy) px and principal point ``cx, cy``
    (default the image centre ((W − 1)/2, (H − 1)/2)); its pixel (u, v) with depth Z (mm, along its optical
    axis) is the point ``Z · ((u − cx)/fx, (v − cy)/fy, 1)`` of its own frame. The surface is the mesh of
    these points: every cell of four neighbouring pixels is two flat triangles, (u, v)–(u+1, v)–(u+1, v+1)
    and (u, v)–(u+1, v+1)–(u, v+1), intersected by rays exactly (:mod:`.kernels`); a hit's colour is the
    image, bilinear, at the hit's projection into the source camera (which is what it photographed).

    Pose and size: a world point is ``origin + scale · R · p`` with p in the source frame and R the
    rotation of ``rotation`` (:func:`euler_to_matrix`), so the object is a similar copy of the photographed
    scene (``scale`` < 1: smaller) seen by the source camera from ``origin``. :meth:`placed` puts the
    scene's median depth at a chosen world depth.

    Ground truth is unknown (NaN points, inf in ``depth_gt.pfm``) where a ray hits a triangle that is
    stretched across a depth jump, i.e. whose three depths spread by more than ``jump`` times the smallest
    (the "skin" a depth map spans between a foreground edge and the background), and where a triangle
    touches a pixel of unknown depth. Unknown depths are filled for rendering (each with the farther of the
    nearest known depths to its left and right in its row: occlusions in a stereo depth map are background).

    Attributes
    ----------
    image : (H, W, 3) uint8/uint16/float array (or (H, W) grey)
        Colour, RGB.
    depth : (H, W) float array
        Depth Z in mm in the source camera frame; NaN, inf or ≤ 0 = unknown.
    focal : (fx, fy)
        Source camera focal lengths, px.
    principal_point : (cx, cy) or None
        Px; None = ((W − 1)/2, (H − 1)/2).
    origin : (3,)
        World position of the source camera's centre, mm.
    rotation : (3,)
        Extrinsic XYZ Euler angles of the source camera's axes in the world, degrees.
    scale : float
        Size of the copy relative to the photographed scene (> 0).
    jump : float
        Relative depth spread above which a triangle is skin (> 0).
    name : str
    source : mapping
        How the object was read (file paths and calibration), written back to a resolved scene file.
    """

    image: np.ndarray = field(repr=False, compare=False, default_factory=lambda: np.zeros((2, 2, 3)))
    depth: np.ndarray = field(repr=False, compare=False, default_factory=lambda: np.ones((2, 2)))
    focal: tuple[float, float] = (1000.0, 1000.0)
    principal_point: tuple[float, float] | None = None
    origin: Vec3 = (0.0, 0.0, 0.0)
    rotation: Vec3 = _IDENTITY
    scale: float = 1.0
    jump: float = 0.02
    name: str = ""
    source: dict[str, Any] = field(default_factory=dict, compare=False, repr=False)

    def __post_init__(self) -> None:
        img = np.asarray(self.image)
        if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] < 3) or min(img.shape[:2]) < 2:
            raise ConfigError(f"RGBDSurface image: expected an H×W×3 (or H×W) array with H, W >= 2, got shape "
                              f"{img.shape}")
        dep = np.asarray(self.depth)
        if dep.ndim != 2 or not np.issubdtype(dep.dtype, np.number):
            raise ConfigError(f"RGBDSurface depth: expected an H×W array of numbers, got shape {dep.shape}")
        if dep.shape != img.shape[:2]:
            raise ConfigError(f"RGBDSurface depth: expected the colour image's size {img.shape[1]}×{img.shape[0]}, "
                              f"got {dep.shape[1]}×{dep.shape[0]}; give a depth map of the same view and size")
        d = np.asarray(dep, dtype=np.float64)
        with np.errstate(invalid="ignore"):
            known = np.isfinite(d) & (d > 0)
        if not known.any():
            raise ConfigError("RGBDSurface depth: expected some known (finite, positive) depths, got none")
        object.__setattr__(self, "depth", np.where(known, d, np.nan))
        _vec(self, "focal", 2, positive=True)
        if self.principal_point is not None:
            _vec(self, "principal_point", 2)
        _vec(self, "origin", 3)
        _vec(self, "rotation", 3)
        _scalar(self, "scale", positive=True)
        _scalar(self, "jump", positive=True)

    @property
    def size(self) -> tuple[int, int]:
        """(W, H) of the source images, px."""
        return (int(self.depth.shape[1]), int(self.depth.shape[0]))

    @property
    def center(self) -> tuple[float, float]:
        """(cx, cy) of the source camera, px."""
        if self.principal_point is not None:
            return (float(self.principal_point[0]), float(self.principal_point[1]))
        w, h = self.size
        return ((w - 1) / 2.0, (h - 1) / 2.0)

    @property
    def matrix(self) -> np.ndarray:
        """(3, 3) source-camera-to-world rotation; columns are the source camera's axes."""
        return euler_to_matrix(self.rotation)

    @property
    def median_depth(self) -> float:
        """Median of the known source depths, mm (before scaling)."""
        return float(np.nanmedian(self.depth))

    def points(self) -> np.ndarray:
        """(H, W, 3) world points of the depth map's pixels (the mesh vertices), mm; NaN where unknown."""
        w, h = self.size
        cx, cy = self.center
        vv, uu = np.mgrid[0:h, 0:w].astype(np.float64)
        z = self.depth
        local = np.stack([(uu - cx) / self.focal[0] * z, (vv - cy) / self.focal[1] * z, z], axis=-1)
        return self.scale * local @ self.matrix.T + np.asarray(self.origin)

    @classmethod
    def placed(cls, image: np.ndarray, depth: np.ndarray, *, focal: tuple[float, float],
               center_depth: float, principal_point: tuple[float, float] | None = None,
               scale: float | None = None, width: float | None = None, jump: float = 0.02, name: str = "",
               source: dict[str, Any] | None = None) -> RGBDSurface:
        """The scene facing the camera with its median depth at world depth ``center_depth`` (mm).

        The source camera looks along world +Z from ``(0, 0, center_depth − scale · median_depth)``.
        ``scale`` default: ``center_depth / median_depth`` (the source camera at the real camera's centre,
        so the copy fills the same angles as the photograph); ``width`` (mm) instead: the scale at which
        the photograph's field is ``width`` wide at its median depth.
        """
        if scale is not None and width is not None:
            raise ConfigError(f"RGBDSurface: expected scale or width, got both ({scale!r}, {width!r})")
        probe = cls(image=image, depth=depth, focal=focal, principal_point=principal_point, jump=jump, name=name)
        if isinstance(center_depth, bool) or not isinstance(center_depth, int | float) \
                or not math.isfinite(center_depth) or center_depth <= 0:
            raise ConfigError(f"RGBDSurface center_depth: expected a positive number of mm, got {center_depth!r}")
        zmed = probe.median_depth
        if width is not None:
            if isinstance(width, bool) or not isinstance(width, int | float) or not math.isfinite(width) \
                    or width <= 0:
                raise ConfigError(f"RGBDSurface width: expected a positive number of mm, got {width!r}")
            scale = float(width) / (probe.size[0] * zmed / probe.focal[0])
        s = float(center_depth) / zmed if scale is None else scale
        return cls(image=image, depth=depth, focal=focal, principal_point=principal_point,
                   origin=(0.0, 0.0, float(center_depth) - float(s) * zmed), scale=s, jump=jump, name=name,
                   source=dict(source or {}))


SceneObject = Rectangle | Box | Sphere | Plane | RGBDSurface


BAYER_PATTERNS = ("RGGB", "BGGR", "GRBG", "GBRG")
DEMOSAIC_METHODS = ("bilinear", "edge-aware", "vng")


@dataclass(frozen=True)
class ThinLens:
    """A thin lens at the optical centre (docs/scenes.md): defocus and the apex band come from tracing.

    Each pixel sample is ``samples`` rays from points spread over the entrance pupil (diameter
    focal length / ``f_number``, :func:`prismstereo.optics.lens.aperture_points`) toward the sample's in-focus
    point on the plane z = ``focus_distance``, each traced through the face it meets.

    Attributes
    ----------
    f_number : float
        N (≥ 0.5).
    focus_distance : float
        Distance of the plane in focus, mm along the optical axis (> 0).
    samples : int
        Aperture rays per pixel sample (1..256).
    """

    f_number: float = 8.0
    focus_distance: float = 1400.0
    samples: int = 16

    def __post_init__(self) -> None:
        _scalar(self, "f_number", lo=0.5, hi=1000.0)
        _scalar(self, "focus_distance", positive=True)
        if isinstance(self.samples, bool) or not isinstance(self.samples, int | np.integer) \
                or not 1 <= self.samples <= 256:
            raise ConfigError(f"ThinLens samples: expected an integer in 1..256, got {self.samples!r}")


@dataclass(frozen=True)
class Scene:
    """Objects plus render settings.

    Attributes
    ----------
    objects : tuple of SceneObject
        Object ids in every output are indices into this tuple.
    background : RGB
        Colour of rays that pass the prism and hit nothing.
    shading : float
        Strength in [0, 1] of a fixed Lambertian light (view-independent, so both virtual views see the
        same radiance); 0 renders pure albedo.
    noise : float
        Standard deviation of additive Gaussian sensor noise, grey levels (0 = none).
    seed : int
        Seed of the sensor noise.
    supersample : int
        Default samples per pixel side.
    name : str
    vignetting : float
        Fraction of light lost at the image corners, in [0, 1): the irradiance falls off as
        1 − vignetting·(r / r_corner)² with the distance r from the principal point (0 = none).
    abbe : float or None
        Abbe number V_d of the glass for dispersion: the red, green and blue channels are rendered with
        the refractive indices of the C (656 nm), d (588 nm) and F (486 nm) lines of a Cauchy glass with
        n_d = the rig's index and n_F − n_C = (n_d − 1) / V_d, which gives colour fringes. None = no dispersion.
    lens : ThinLens or None
        A thin lens (defocus, and the band around the apex line where two views mix); None = a pinhole.
    bayer : str or None
        Colour filter mosaic ("RGGB", "BGGR", "GRBG", "GBRG": the colours of the top-left 2×2 pixels, row by
        row): the sensor records one channel per pixel (noise is added to it), and the image is demosaiced
        with ``demosaic``; None = every pixel records RGB.
    demosaic : str
        "bilinear", "edge-aware" or "vng" (OpenCV's Bayer conversions).
    jpeg_quality : int or None
        Store the capture as a JPEG of this quality (1..100) and decode it; None = lossless.
    """

    objects: tuple[SceneObject, ...] = ()
    background: Color = (0.0, 0.0, 0.0)
    shading: float = 0.0
    noise: float = 0.0
    seed: int = 0
    supersample: int = 2
    name: str = "scene"
    vignetting: float = 0.0
    abbe: float | None = None
    lens: ThinLens | None = None
    bayer: str | None = None
    demosaic: str = "edge-aware"
    jpeg_quality: int | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "objects", tuple(self.objects))
        _vec(self, "background", 3, lo=0.0, hi=1.0)
        _scalar(self, "shading", lo=0.0, hi=1.0)
        _scalar(self, "noise", lo=0.0, hi=255.0)
        _scalar(self, "vignetting", lo=0.0, hi=0.99)
        if self.abbe is not None:
            _scalar(self, "abbe", lo=10.0, hi=120.0)
        if self.lens is not None and not isinstance(self.lens, ThinLens):
            raise ConfigError(f"Scene lens: expected a ThinLens or None, got {self.lens!r}")
        if self.bayer is not None and self.bayer not in BAYER_PATTERNS:
            raise ConfigError(f"Scene bayer: expected one of {', '.join(BAYER_PATTERNS)} or None, got {self.bayer!r}")
        if self.demosaic not in DEMOSAIC_METHODS:
            raise ConfigError(f"Scene demosaic: expected one of {', '.join(DEMOSAIC_METHODS)}, got {self.demosaic!r}")
        if self.jpeg_quality is not None and (isinstance(self.jpeg_quality, bool)
                                              or not isinstance(self.jpeg_quality, int | np.integer)
                                              or not 1 <= self.jpeg_quality <= 100):
            raise ConfigError(f"Scene jpeg_quality: expected an integer in 1..100 or None, got {self.jpeg_quality!r}")
