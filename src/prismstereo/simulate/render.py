"""Ray–scene intersection and the prism-capture renderer.

The renderer traces, for every real pixel, s × s sub-pixel rays through the prism (exact refraction,
:func:`prismstereo.optics.trace_pixels`) plus one ray through the pixel centre, intersects them with the
scene in a parallel numba kernel and averages the colours of the valid samples. Ground truth (depth, hit
point, face, object) comes from the pixel-centre ray, so it is exact for that ray.
"""

from __future__ import annotations

import logging
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np

from prismstereo.config import Rig
from prismstereo.errors import ConfigError
from prismstereo.optics import trace_rays
from prismstereo.optics.distortion import undistort_points
from prismstereo.optics.lens import aperture_diameter, aperture_points
from prismstereo.simulate.kernels import (
    LIGHT,
    CompiledScene,
    average_samples_kernel,
    compile_scene,
    trace_scene_kernel,
)
from prismstereo.simulate.scene import Scene

log = logging.getLogger(__name__)

NO_FACE = 255
_RAYS_PER_CHUNK = 1 << 13
_RAYS_PER_BLOCK = 1 << 18


@dataclass(frozen=True)
class SceneHits:
    """Nearest hits of N rays with a scene.

    Attributes
    ----------
    distance : (N,) float64
        Distance along the ray from its origin to the hit, mm; NaN where the ray hits nothing.
    points : (N, 3) float64
        Hit points in the world frame, mm; NaN rows for misses.
    object_id : (N,) int32
        Index into ``scene.objects``; −1 for misses.
    colors : (N, 3) float32
        RGB in [0, 1] (texture × optional shading); NaN rows for misses.
    """

    distance: np.ndarray
    points: np.ndarray
    object_id: np.ndarray
    colors: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        """(N,) bool."""
        return self.object_id >= 0

    @property
    def depth(self) -> np.ndarray:
        """(N,) world Z of the hit points, mm (the depth ground truth); NaN for misses."""
        return self.points[:, 2]


def intersect_scene(
    origins: np.ndarray,
    directions: np.ndarray,
    scene: Scene | CompiledScene,
    *,
    shading: float | None = None,
) -> SceneHits:
    """Intersect rays with a scene: nearest hit, its point, object and colour.

    Parameters
    ----------
    origins : (N, 3) float64
        Ray origins, mm, world frame. Rows containing NaN (invalid rays) give misses.
    directions : (N, 3) float64
        Ray directions (need not be unit).
    scene : Scene or CompiledScene
    shading : float, optional
        Lambertian shading strength in [0, 1]; default ``scene.shading`` (0 for a compiled scene).

    Returns
    -------
    SceneHits
    """
    o = np.ascontiguousarray(np.asarray(origins, dtype=np.float64).reshape(-1, 3))
    d = np.ascontiguousarray(np.asarray(directions, dtype=np.float64).reshape(-1, 3))
    if o.shape != d.shape:
        raise ConfigError(f"expected origins and directions of the same shape, got {o.shape} and {d.shape}")
    if isinstance(scene, Scene):
        shade = scene.shading if shading is None else shading
        compiled = compile_scene(scene)
    else:
        shade = 0.0 if shading is None else shading
        compiled = scene
    n = o.shape[0]
    distance = np.empty(n)
    object_id = np.empty(n, dtype=np.int32)
    points = np.empty((n, 3))
    colors = np.empty((n, 3), dtype=np.float32)
    trace_scene_kernel(o, d, compiled.prims, compiled.textures, compiled.pixels, compiled.fields, compiled.flags,
                       float(shade), LIGHT, distance, object_id, points, colors)
    return SceneHits(distance=distance, points=points, object_id=object_id, colors=colors)


@dataclass(frozen=True)
class Capture:
    """A rendered prism capture with exact ground truth per real pixel.

    Attributes
    ----------
    image : (H, W, 3) uint8
        RGB capture (colour averaged over the valid sub-pixel samples; black where no sample is valid).
    depth : (H, W) float32
        World Z (mm) of the scene point seen by the pixel-centre ray; NaN where the ray is invalid or hits
        nothing.
    faces : (H, W) uint8
        Face index the pixel-centre ray passes through; 255 where the ray is invalid.
    points : (H, W, 3) float64
        World point (mm) seen by the pixel centre; NaN where none. Exact correspondences: the same point seen
        in two sub-images is the same scene point.
    object_ids : (H, W) int16
        Index of the scene object seen by the pixel centre; −1 where none.
    supersample : int
    seconds : float
        Wall time of the render.
    """

    image: np.ndarray
    depth: np.ndarray
    faces: np.ndarray
    points: np.ndarray
    object_ids: np.ndarray
    supersample: int
    seconds: float

    @property
    def coverage(self) -> float:
        """Fraction of pixels with a ground-truth depth."""
        return float(np.mean(np.isfinite(self.depth)))

    def face_coverage(self) -> dict[int, float]:
        """Fraction of the image each face occupies (from the pixel-centre rays)."""
        ids, counts = np.unique(self.faces[self.faces != NO_FACE], return_counts=True)
        return {int(k): float(c) / self.faces.size for k, c in zip(ids, counts, strict=True)}


def _trace(rig: Rig, pixels: np.ndarray, prism: bool, aperture: np.ndarray | None = None,
           focus: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Rays of real pixels (N, 2): what :func:`prismstereo.optics.trace_pixels` gives, without its
    per-call inverse of K (the pinhole direction K⁻¹[u, v, 1] is computed directly; trace_rays normalises).

    With ``aperture`` (N, 2), mm: thin-lens rays, each from its aperture point (x, y, 0) toward the pixel's
    in-focus point ``focus · (x_n, y_n, 1)`` (x_n, y_n its undistorted normalised point), through the prism."""
    cam = rig.camera
    cx, cy = cam.center
    d = np.empty((pixels.shape[0], 3))
    if cam.fx is None:
        f = cam.focal_px
        d[:, 0] = (pixels[:, 0] - cx) / f
        d[:, 1] = (pixels[:, 1] - cy) / f
    else:
        fx, fy = cam.focal_xy
        d[:, 0] = (pixels[:, 0] - cx) / fx
        d[:, 1] = (pixels[:, 1] - cy) / fy
    if cam.has_distortion:
        d[:, :2] = undistort_points(d[:, :2], cam.distortion)
    d[:, 2] = 1.0
    o = None
    if aperture is not None:
        o = np.zeros_like(d)
        o[:, :2] = aperture
        d = d * focus - o
    if prism:
        b = trace_rays(rig, d, origins=o)
        return b.origins, b.directions, b.face, b.valid
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    n = pixels.shape[0]
    return (np.zeros((n, 3)) if o is None else o), d, np.zeros(n, dtype=np.int64), np.ones(n, dtype=bool)


def sample_offsets(supersample: int) -> np.ndarray:
    """(s², 2) sub-pixel offsets (du, dv) of a regular s × s grid inside the pixel, row-major."""
    g = (np.arange(supersample) + 0.5) / supersample - 0.5
    du, dv = np.meshgrid(g, g)
    return np.stack([du.ravel(), dv.ravel()], axis=1)


def dispersed_indices(n_d: float, abbe: float) -> tuple[float, float, float]:
    """Refractive indices (n_C, n_d, n_F) at 656.3, 587.6 and 486.1 nm of a Cauchy glass n = A + B/λ²
    with index ``n_d`` and Abbe number ``abbe`` = (n_d − 1)/(n_F − n_C): the red, green, blue channels."""
    lc, ld, lf = 0.6563, 0.5876, 0.4861  # µm
    b = (n_d - 1.0) / abbe / (1.0 / lf**2 - 1.0 / lc**2)
    a = n_d - b / ld**2
    return (a + b / lc**2, n_d, a + b / lf**2)


def vignetting_gain(rig: Rig, strength: float) -> np.ndarray:
    """(H, W) float32 irradiance factor 1 − strength·(r / r_corner)², r the distance to the principal point."""
    W, H = rig.camera.width, rig.camera.height
    cx, cy = rig.camera.center
    vv, uu = np.mgrid[0:H, 0:W].astype(np.float64)
    r2 = (uu - cx) ** 2 + (vv - cy) ** 2
    r2max = max((x - cx) ** 2 + (y - cy) ** 2 for x in (0, W - 1) for y in (0, H - 1))
    return (1.0 - strength * r2 / r2max).astype(np.float32)


def _render_pass(
    rig: Rig, scene: Scene, compiled: CompiledScene, s: int, prism: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One render of the linear image (H, W, 3) float32 in [0, 1] and the pixel-centre ground truth."""
    W, H = rig.camera.width, rig.camera.height
    offsets = sample_offsets(s)
    n_samp = s * s
    aperture = None
    focus = 0.0
    if scene.lens is not None:
        # thin lens: sample k has sub-pixel offset k mod s² and aperture point k (a golden-angle spiral, so
        # each sub-pixel position gets points spread over the whole pupil)
        n_samp = max(scene.lens.samples, s * s)
        aperture = aperture_points(n_samp, aperture_diameter(rig, f_number=scene.lens.f_number))
        offsets = offsets[np.arange(n_samp) % (s * s)]
        focus = scene.lens.focus_distance
    background = np.asarray(scene.background, dtype=np.float32)

    image = np.empty((H, W, 3), dtype=np.float32)
    depth = np.empty((H, W), dtype=np.float32)
    faces = np.empty((H, W), dtype=np.uint8)
    points = np.empty((H, W, 3))
    object_ids = np.empty((H, W), dtype=np.int16)

    # Rays are traced (numpy, prismstereo.optics) in small chunks, which is fastest in cache, into blocks of
    # ~256k rays; each block then goes to the parallel numba kernels in one call. A helper thread traces
    # the next block while the kernels (which release the GIL) shade the current one.
    # With odd s the middle sample is the pixel centre; with even s the centre ray is traced in addition.
    extra = 0 if (s % 2 and aperture is None) else 1
    mid = n_samp // 2
    per_row = W * (n_samp + extra)
    block_rows = max(1, _RAYS_PER_BLOCK // per_row)
    chunk_rays = max(1, _RAYS_PER_CHUNK // per_row) * per_row
    us = np.arange(W, dtype=np.float64)

    def trace_block(r0: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        r1 = min(H, r0 + block_rows)
        vv, uu = np.meshgrid(np.arange(r0, r1, dtype=np.float64), us, indexing="ij")
        centres = np.stack([uu, vv], axis=-1)  # (h, W, 2)
        samples = (centres[:, :, None, :] + offsets[None, None, :, :]).reshape(-1, 2)  # (h·W·S, 2)
        px = np.concatenate([centres.reshape(-1, 2), samples]) if extra else samples
        n = px.shape[0]
        ap = None
        if aperture is not None:  # the centre rays are the pinhole's (chief rays): the ground truth
            ap = np.concatenate([np.zeros((centres.shape[0] * W, 2)),
                                 np.broadcast_to(aperture, (centres.shape[0] * W, n_samp, 2)).reshape(-1, 2)])
        origins = np.empty((n, 3))
        dirs = np.empty((n, 3))
        face = np.empty(n, dtype=np.int64)
        valid = np.empty(n, dtype=bool)
        for c0 in range(0, n, chunk_rays):
            c1 = min(n, c0 + chunk_rays)
            origins[c0:c1], dirs[c0:c1], face[c0:c1], valid[c0:c1] = _trace(
                rig, px[c0:c1], prism, None if ap is None else ap[c0:c1], focus)
        return origins, dirs, face, valid

    starts = list(range(0, H, block_rows))
    with ThreadPoolExecutor(max_workers=1) as pool:
        pending = pool.submit(trace_block, starts[0])
        for i, r0 in enumerate(starts):
            origins, dirs, face, valid = pending.result()
            if i + 1 < len(starts):
                pending = pool.submit(trace_block, starts[i + 1])
            r1 = min(H, r0 + block_rows)
            h = r1 - r0
            nc = h * W
            hits = intersect_scene(origins, dirs, compiled, shading=scene.shading)
            # pixel-centre ground truth
            if extra:
                c_valid, c_face = valid[:nc], face[:nc]
                c_points, c_ids = hits.points[:nc], hits.object_id[:nc]
            else:
                c_valid = valid.reshape(nc, n_samp)[:, mid]
                c_face = face.reshape(nc, n_samp)[:, mid]
                c_points = hits.points.reshape(nc, n_samp, 3)[:, mid]
                c_ids = hits.object_id.reshape(nc, n_samp)[:, mid]
            faces[r0:r1] = np.where(c_valid, c_face, NO_FACE).reshape(h, W).astype(np.uint8)
            points[r0:r1] = c_points.reshape(h, W, 3)
            depth[r0:r1] = c_points[:, 2].reshape(h, W)
            object_ids[r0:r1] = c_ids.reshape(h, W)
            # colour: average of the valid samples; valid rays that hit nothing see the background
            k0 = nc * extra
            avg = np.empty((nc, 3), dtype=np.float32)
            average_samples_kernel(hits.colors[k0:], np.ascontiguousarray(valid[k0:]), n_samp, background, avg)
            image[r0:r1] = avg.reshape(h, W, 3)

    return image, depth, faces, points, object_ids


#: OpenCV names a Bayer pattern by the second row's second and third pixels: RGGB is its "BG".
_CV_BAYER = {"RGGB": "BG", "BGGR": "RG", "GRBG": "GB", "GBRG": "GR"}
_CV_DEMOSAIC = {"bilinear": "", "edge-aware": "_EA", "vng": "_VNG"}
_PATTERN_CHANNEL = {p: [["RGB".index(p[0]), "RGB".index(p[1])], ["RGB".index(p[2]), "RGB".index(p[3])]]
                    for p in _CV_BAYER}


def bayer_mosaic(image: np.ndarray, pattern: str) -> np.ndarray:
    """(H, W) one channel per pixel of an (H, W, 3) RGB image through a colour filter array.

    ``pattern`` names the colours of the top-left 2×2 pixels row by row ("RGGB", "BGGR", "GRBG", "GBRG").
    """
    if pattern not in _PATTERN_CHANNEL:
        raise ConfigError(f"bayer: expected one of {', '.join(_PATTERN_CHANNEL)}, got {pattern!r}")
    img = np.asarray(image)
    out = np.empty(img.shape[:2], dtype=img.dtype)
    ch = _PATTERN_CHANNEL[pattern]
    for i in range(2):
        for j in range(2):
            out[i::2, j::2] = img[i::2, j::2, ch[i][j]]
    return out


def demosaic(mosaic: np.ndarray, pattern: str, *, method: str = "edge-aware") -> np.ndarray:
    """(H, W, 3) uint8 RGB from an (H, W) uint8 Bayer mosaic (OpenCV's bilinear, edge-aware or VNG)."""
    if pattern not in _CV_BAYER:
        raise ConfigError(f"bayer: expected one of {', '.join(_CV_BAYER)}, got {pattern!r}")
    if method not in _CV_DEMOSAIC:
        raise ConfigError(f"demosaic: expected one of {', '.join(_CV_DEMOSAIC)}, got {method!r}")
    code = getattr(cv2, f"COLOR_Bayer{_CV_BAYER[pattern]}2RGB{_CV_DEMOSAIC[method]}")
    return np.ascontiguousarray(cv2.cvtColor(np.ascontiguousarray(mosaic, dtype=np.uint8), code))


def jpeg_roundtrip(image: np.ndarray, *, quality: int) -> np.ndarray:
    """An (H, W, 3) uint8 RGB image after JPEG encoding at ``quality`` (1..100, OpenCV/libjpeg, 4:2:0) and
    decoding: what a camera that saves JPEG gives."""
    if isinstance(quality, bool) or not isinstance(quality, int | np.integer) or not 1 <= quality <= 100:
        raise ConfigError(f"jpeg_quality: expected an integer in 1..100, got {quality!r}")
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(image[..., ::-1]), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:  # pragma: no cover - OpenCV always encodes a uint8 image
        raise ConfigError("jpeg_quality: OpenCV could not encode the capture as JPEG")
    decoded = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    if decoded is None:  # pragma: no cover
        raise ConfigError("jpeg_quality: OpenCV could not decode its own JPEG")
    return np.ascontiguousarray(np.asarray(decoded)[..., ::-1])


def render_capture(
    rig: Rig,
    scene: Scene,
    *,
    supersample: int | None = None,
    prism: bool = True,
    noise: float | None = None,
    seed: int | None = None,
) -> Capture:
    """Render what the real camera sees of ``scene`` through the rig's prism.

    Parameters
    ----------
    rig : Rig
    scene : Scene
    supersample : int, optional
        s: s × s regular samples per pixel for antialiasing (default ``scene.supersample``).
    prism : bool
        False renders what the bare camera sees (no prism; every valid pixel gets face 0): a reference.
    noise : float, optional
        Std of additive Gaussian sensor noise in grey levels (default ``scene.noise``).
    seed : int, optional
        Seed of the sensor noise (default ``scene.seed``). The render is deterministic.

    Notes
    -----
    The camera model is the rig's: a distorting lens (``rig.camera.distortion``) and a misaligned prism
    (``tilt``, ``decenter``) are rendered exactly; ``scene.lens`` (a thin lens) traces each sample from
    points across the aperture through its in-focus point (defocus, the apex band). The sensor then applies,
    in this order, the scene's vignetting, dispersion (red and blue channels traced with their own index
    when ``scene.abbe`` is set), the Bayer mosaic (``scene.bayer``: one channel per pixel), additive
    Gaussian noise, rounding to 8 bits, demosaicing and JPEG compression (``scene.jpeg_quality``).
    Ground truth is always the pixel centre's chief ray (the pinhole ray).

    Returns
    -------
    Capture
        ``image`` (H, W, 3) uint8, ``depth`` (H, W) float32 mm, ``faces`` (H, W) uint8, ``points``
        (H, W, 3) float64, ``object_ids`` (H, W) int16.
    """
    t0 = time.perf_counter()
    s = scene.supersample if supersample is None else supersample
    if isinstance(s, bool) or not isinstance(s, int | np.integer) or not 1 <= s <= 16:
        raise ConfigError(f"supersample: expected an integer in 1..16, got {s!r}")
    s = int(s)
    sigma = scene.noise if noise is None else float(noise)
    if not np.isfinite(sigma) or sigma < 0:
        raise ConfigError(f"noise: expected a non-negative number of grey levels, got {sigma!r}")
    compiled = compile_scene(scene)
    image, depth, faces, points, object_ids = _render_pass(rig, scene, compiled, s, prism)
    if prism and scene.abbe is not None:
        # dispersion: red and blue through the glass of their own index; the ground truth stays the green's
        for channel, n_c in ((0, dispersed_indices(rig.prism.refractive_index, scene.abbe)[0]),
                             (2, dispersed_indices(rig.prism.refractive_index, scene.abbe)[2])):
            other = _render_pass(rig.with_prism(refractive_index=n_c), scene, compiled, s, prism)[0]
            image[..., channel] = other[..., channel]
    W, H = rig.camera.width, rig.camera.height
    out = image * np.float32(255.0)
    if scene.vignetting > 0:
        out *= vignetting_gain(rig, scene.vignetting)[..., None]
    if scene.bayer is not None:
        out = bayer_mosaic(out, scene.bayer)
    if sigma > 0:
        rng = np.random.default_rng(scene.seed if seed is None else seed)
        out += rng.normal(0.0, sigma, size=out.shape).astype(np.float32)
    img8 = np.clip(np.rint(out), 0, 255).astype(np.uint8)
    if scene.bayer is not None:
        img8 = demosaic(img8, scene.bayer, method=scene.demosaic)
    if scene.jpeg_quality is not None:
        img8 = jpeg_roundtrip(img8, quality=scene.jpeg_quality)
    dt = time.perf_counter() - t0
    log.info("rendered %dx%d with %dx%d supersampling in %.2f s", W, H, s, s, dt)
    return Capture(image=img8, depth=depth, faces=faces, points=points, object_ids=object_ids,
                   supersample=s, seconds=dt)
