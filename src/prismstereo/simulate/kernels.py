"""Numba kernels of the simulator: ray–scene intersection and texture lookup over flat arrays.

A :class:`~prismstereo.simulate.scene.Scene` is compiled once into three arrays (see
:func:`compile_scene`): primitives (one row per rectangle, box face, sphere or plane), textures (one row
each) and the concatenated pixels of image textures. The kernel loops over rays in parallel and over the
(few) primitives inside; no Python loop touches a pixel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba
import numpy as np

from prismstereo.simulate.rgbd import surface_mesh
from prismstereo.simulate.scene import (
    Box,
    CheckerTexture,
    ImageTexture,
    NoiseTexture,
    Plane,
    Rectangle,
    RGBDSurface,
    Scene,
    SolidTexture,
    Sphere,
    Texture,
)

# primitive kinds; BOUND is a bounding sphere (centre, radius at column 13) that guards the next
# ``int(row[14])`` primitives: a ray that misses it skips them (the six faces of a box).
# HFIELD is an RGB-D surface (a triangulated height field over its source camera's pixel grid, see
# :func:`_hit_field`): columns 13 = scale, 22..31 = W, H, fx, fy, cx, cy, depth offset, zmin, zmax, flag offset.
RECT, SPHERE, PLANE, BOUND, HFIELD = 0, 1, 2, 3, 4
# texture kinds
T_SOLID, T_CHECKER, T_NOISE, T_IMAGE = 0, 1, 2, 3

PRIM_WIDTH = 32  # kind, c(3), e1(3), e2(3), e3(3), a, b, tex, obj, salt, ext_s, ext_t, s0, t0, 10 field values
TEX_WIDTH = 16

# A fixed light for the optional Lambertian shading: direction toward the light (up-left, toward the camera).
LIGHT = np.array([-0.35, -0.55, -0.76]) / np.linalg.norm([-0.35, -0.55, -0.76])


@dataclass(frozen=True)
class CompiledScene:
    """Flat arrays of a scene for the kernels.

    Attributes
    ----------
    prims : (P, 32) float64
    textures : (T, 16) float64
    pixels : (K,) float32, all image textures' RGB values concatenated
    fields : (F,) float64, the filled depth maps of all RGB-D surfaces concatenated (row-major), mm
    flags : (G,) uint8, their per-cell unknown-triangle flags (:func:`~prismstereo.simulate.rgbd.surface_mesh`)
    """

    prims: np.ndarray
    textures: np.ndarray
    pixels: np.ndarray
    fields: np.ndarray = field(default_factory=lambda: np.zeros(1))
    flags: np.ndarray = field(default_factory=lambda: np.zeros(1, dtype=np.uint8))


def _tex_row(tex: Texture, pixel_chunks: list[np.ndarray], offset: int) -> tuple[np.ndarray, int]:
    row = np.zeros(TEX_WIDTH)
    if isinstance(tex, SolidTexture):
        row[0] = T_SOLID
        row[1:4] = tex.color
    elif isinstance(tex, CheckerTexture):
        row[0] = T_CHECKER
        row[1] = tex.square
        row[2:5] = tex.colors[0]
        row[5:8] = tex.colors[1]
        if tex.squares is not None:
            row[8], row[9] = tex.squares
        row[10] = tex.margin
        row[11:14] = tex.border_color
    elif isinstance(tex, NoiseTexture):
        row[0] = T_NOISE
        row[1:6] = (tex.scale, tex.octaves, tex.persistence, tex.contrast, tex.seed % (1 << 30))
    elif isinstance(tex, ImageTexture):
        img = tex.as_float()
        row[0] = T_IMAGE
        row[1] = offset
        row[2], row[3] = img.shape[1], img.shape[0]
        if tex.size is not None:
            row[4], row[5] = tex.size
        pixel_chunks.append(img.reshape(-1))
        offset += img.size
    else:  # pragma: no cover - guarded by the dataclass types
        raise TypeError(f"unknown texture {tex!r}")
    return row, offset


def _prim(kind: int, c: np.ndarray, R: np.ndarray, a: float, b: float, obj: int, salt: int,
          ext: tuple[float, float], st0: tuple[float, float]) -> np.ndarray:
    row = np.zeros(PRIM_WIDTH)
    row[0] = kind
    row[1:4] = c
    row[4:7], row[7:10], row[10:13] = R[:, 0], R[:, 1], R[:, 2]
    row[13], row[14] = a, b
    row[16], row[17] = obj, salt
    row[18], row[19] = ext
    row[20], row[21] = st0
    return row


def _box_faces(box: Box) -> list[tuple[np.ndarray, np.ndarray, float, float]]:
    """Six (centre, axes (3×3, columns e1 e2 normal-axis), half s, half t) rectangles of a box."""
    R = box.matrix
    c = np.asarray(box.center, dtype=np.float64)
    hx, hy, hz = (s / 2.0 for s in box.size)
    x, y, z = R[:, 0], R[:, 1], R[:, 2]
    faces = [
        (c - hz * z, np.stack([x, y, z], 1), hx, hy),  # front (−Z local)
        (c + hz * z, np.stack([-x, y, -z], 1), hx, hy),  # back
        (c - hx * x, np.stack([-z, y, x], 1), hz, hy),  # left (−X)
        (c + hx * x, np.stack([z, y, -x], 1), hz, hy),  # right
        (c - hy * y, np.stack([x, z, -y], 1), hx, hz),  # top (−Y = up)
        (c + hy * y, np.stack([x, -z, y], 1), hx, hz),  # bottom
    ]
    return faces


def compile_scene(scene: Scene) -> CompiledScene:
    """Flatten a scene into the kernel arrays (textures deduplicated per object)."""
    prims: list[np.ndarray] = []
    tex_rows: list[np.ndarray] = []
    chunks: list[np.ndarray] = []
    field_chunks: list[np.ndarray] = []
    flag_chunks: list[np.ndarray] = []
    n_field = n_flag = 0
    offset = 0
    for obj_id, obj in enumerate(scene.objects):
        if isinstance(obj, RGBDSurface):
            w, h = obj.size
            texture: Texture = ImageTexture(image=obj.image, size=(float(w), float(h)))
            trow, offset = _tex_row(texture, chunks, offset)
            tex_rows.append(trow)
            depth, flags = surface_mesh(obj)
            row = _prim(HFIELD, np.asarray(obj.origin, dtype=np.float64), obj.matrix, obj.scale, 0.0, obj_id, 0,
                        (0.0, 0.0), (0.0, 0.0))
            row[15] = len(tex_rows) - 1
            cx, cy = obj.center
            row[22:32] = (w, h, obj.focal[0], obj.focal[1], cx, cy, n_field, float(depth.min()),
                          float(depth.max()), n_flag)
            prims.append(row)
            field_chunks.append(depth.ravel())
            flag_chunks.append(flags.ravel())
            n_field += depth.size
            n_flag += flags.size
            continue
        trow, offset = _tex_row(obj.texture, chunks, offset)
        tex_id = len(tex_rows)
        tex_rows.append(trow)
        c = np.asarray(obj.center, dtype=np.float64)
        if isinstance(obj, Rectangle):
            a, b = obj.size[0] / 2.0, obj.size[1] / 2.0
            prims.append(_prim(RECT, c, obj.matrix, a, b, obj_id, 0, (2 * a, 2 * b), (a, b)))
        elif isinstance(obj, Box):
            bound = _prim(BOUND, c, np.eye(3), 0.5 * math.hypot(*obj.size) * (1 + 1e-9), 6, obj_id, 0,
                          (0.0, 0.0), (0.0, 0.0))
            prims.append(bound)
            for k, (fc, axes, a, b) in enumerate(_box_faces(obj)):
                prims.append(_prim(RECT, fc, axes, a, b, obj_id, k, (2 * a, 2 * b), (a, b)))
        elif isinstance(obj, Sphere):
            r = obj.radius
            prims.append(_prim(SPHERE, c, obj.matrix, r, r, obj_id, 0, (2 * math.pi * r, math.pi * r), (0, 0)))
        elif isinstance(obj, Plane):
            prims.append(_prim(PLANE, c, obj.matrix, math.inf, math.inf, obj_id, 0, (0.0, 0.0), (0, 0)))
        else:  # pragma: no cover
            raise TypeError(f"unknown scene object {obj!r}")
        n_rows = 7 if isinstance(obj, Box) else 1
        for row in prims[-n_rows:]:
            row[15] = tex_id
    prim_arr = np.stack(prims) if prims else np.zeros((0, PRIM_WIDTH))
    tex_arr = np.stack(tex_rows) if tex_rows else np.zeros((0, TEX_WIDTH))
    pix = np.concatenate(chunks).astype(np.float32) if chunks else np.zeros(1, np.float32)
    fields = np.concatenate(field_chunks) if field_chunks else np.zeros(1)
    flag_arr = np.concatenate(flag_chunks).astype(np.uint8) if flag_chunks else np.zeros(1, dtype=np.uint8)
    return CompiledScene(prims=np.ascontiguousarray(prim_arr), textures=np.ascontiguousarray(tex_arr), pixels=pix,
                         fields=np.ascontiguousarray(fields, dtype=np.float64), flags=np.ascontiguousarray(flag_arr))


# --------------------------------------------------------------------------- numba helpers
@numba.njit(cache=True, inline="always")
def _hash32(ix: int, iy: int, seed: int) -> int:
    h = (ix * 374761393 + iy * 668265263 + seed * 1274126177) & 0xFFFFFFFF
    h = (((h >> 16) ^ h) * 0x45D9F3B) & 0xFFFFFFFF
    h = (((h >> 16) ^ h) * 0x45D9F3B) & 0xFFFFFFFF
    return (h >> 16) ^ h


@numba.njit(cache=True, inline="always")
def _value_noise3(x: float, y: float, seed: int) -> tuple[float, float, float]:
    """Three independent value-noise channels in [0, 1] at (x, y) (one 30-bit hash per lattice node)."""
    fx = math.floor(x)
    fy = math.floor(y)
    ix = int(fx)
    iy = int(fy)
    tx = x - fx
    ty = y - fy
    sx = tx * tx * tx * (tx * (tx * 6.0 - 15.0) + 10.0)
    sy = ty * ty * ty * (ty * (ty * 6.0 - 15.0) + 10.0)
    w00 = (1.0 - sx) * (1.0 - sy)
    w01 = sx * (1.0 - sy)
    w10 = (1.0 - sx) * sy
    w11 = sx * sy
    ha = _hash32(ix, iy, seed)
    hb = _hash32(ix + 1, iy, seed)
    hc = _hash32(ix, iy + 1, seed)
    hd = _hash32(ix + 1, iy + 1, seed)
    r = (ha & 1023) * w00 + (hb & 1023) * w01 + (hc & 1023) * w10 + (hd & 1023) * w11
    g = ((ha >> 10) & 1023) * w00 + ((hb >> 10) & 1023) * w01 + ((hc >> 10) & 1023) * w10 \
        + ((hd >> 10) & 1023) * w11
    b = ((ha >> 20) & 1023) * w00 + ((hb >> 20) & 1023) * w01 + ((hc >> 20) & 1023) * w10 \
        + ((hd >> 20) & 1023) * w11
    return r / 1023.0, g / 1023.0, b / 1023.0


@numba.njit(cache=True)
def _fbm3(s: float, t: float, scale: float, octaves: int, persistence: float,
          seed: int) -> tuple[float, float, float]:
    """Fractal sum of value-noise octaves, three channels, normalised to [0, 1]."""
    # Each octave is rotated by 40° and doubled in frequency, which hides lattice-aligned artefacts.
    cr = 0.7660444431189780
    sr = 0.6427876096865393
    x = s / scale
    y = t / scale
    r = 0.0
    g = 0.0
    b = 0.0
    norm = 0.0
    amp = 1.0
    for k in range(octaves):
        vr, vg, vb = _value_noise3(x + 17.31 * k, y - 9.73 * k, seed * 64 + k)
        r += amp * vr
        g += amp * vg
        b += amp * vb
        norm += amp
        amp *= persistence
        xr = cr * x - sr * y
        y = 2.0 * (sr * x + cr * y)
        x = 2.0 * xr
    return r / norm, g / norm, b / norm


@numba.njit(cache=True)
def _texture(tex: np.ndarray, pixels: np.ndarray, s: float, t: float, ext_s: float, ext_t: float,
             salt: int) -> tuple[float, float, float]:
    """RGB in [0, 1] of texture row ``tex`` at surface coordinates (s, t) mm."""
    kind = int(tex[0])
    if kind == 0:
        return tex[1], tex[2], tex[3]
    if kind == 1:
        sq = tex[1]
        i = math.floor((s - tex[10]) / sq)
        j = math.floor((t - tex[10]) / sq)
        nx = tex[8]
        ny = tex[9]
        if nx > 0 and (i < 0 or j < 0 or i >= nx or j >= ny):
            return tex[11], tex[12], tex[13]
        if (np.int64(i) + np.int64(j)) % 2 == 0:
            return tex[2], tex[3], tex[4]
        return tex[5], tex[6], tex[7]
    if kind == 2:
        scale = tex[1]
        octaves = int(tex[2])
        pers = tex[3]
        contrast = tex[4]
        nr, ng, nb = _fbm3(s, t, scale, octaves, pers, int(tex[5]) * 8 + salt)
        r = 0.5 + (nr - 0.5) * contrast
        g = 0.5 + (ng - 0.5) * contrast
        b = 0.5 + (nb - 0.5) * contrast
        return min(1.0, max(0.0, r)), min(1.0, max(0.0, g)), min(1.0, max(0.0, b))
    off = np.int64(tex[1])
    w = np.int64(tex[2])
    h = np.int64(tex[3])
    size_s = tex[4] if tex[4] > 0 else ext_s
    size_t = tex[5] if tex[5] > 0 else ext_t
    x = s / size_s * w - 0.5
    y = t / size_t * h - 0.5
    x0f = math.floor(x)
    y0f = math.floor(y)
    fx = x - x0f
    fy = y - y0f
    x0 = np.int64(x0f) % w
    y0 = np.int64(y0f) % h
    x1 = (x0 + 1) % w
    y1 = (y0 + 1) % h
    i00 = off + (y0 * w + x0) * 3
    i01 = off + (y0 * w + x1) * 3
    i10 = off + (y1 * w + x0) * 3
    i11 = off + (y1 * w + x1) * 3
    w00 = (1 - fx) * (1 - fy)
    w01 = fx * (1 - fy)
    w10 = (1 - fx) * fy
    w11 = fx * fy
    r = pixels[i00] * w00 + pixels[i01] * w01 + pixels[i10] * w10 + pixels[i11] * w11
    g = pixels[i00 + 1] * w00 + pixels[i01 + 1] * w01 + pixels[i10 + 1] * w10 + pixels[i11 + 1] * w11
    b = pixels[i00 + 2] * w00 + pixels[i01 + 2] * w01 + pixels[i10 + 2] * w10 + pixels[i11 + 2] * w11
    return r, g, b


@numba.njit(cache=True, inline="always")
def _clip(a: float, b: float, lo: float, hi: float) -> tuple[float, float]:
    """Narrow the ray interval [lo, hi] to the t with a + b·t ≥ 0."""
    if b > 0.0:
        lo = max(lo, -a / b)
    elif b < 0.0:
        hi = min(hi, -a / b)
    elif a < 0.0:
        hi = -math.inf
    return lo, hi


@numba.njit(cache=True, inline="always")
def _triangle(ox: float, oy: float, oz: float, dx: float, dy: float, dz: float,
              ax: float, ay: float, az: float, bx: float, by: float, bz: float,
              cx: float, cy: float, cz: float) -> tuple[float, float, float, float]:
    """Möller–Trumbore: ray parameter of the hit with triangle abc (inf if none) and its normal (b−a)×(c−a)."""
    e1x = bx - ax
    e1y = by - ay
    e1z = bz - az
    e2x = cx - ax
    e2y = cy - ay
    e2z = cz - az
    px = dy * e2z - dz * e2y
    py = dz * e2x - dx * e2z
    pz = dx * e2y - dy * e2x
    det = e1x * px + e1y * py + e1z * pz
    nx = e1y * e2z - e1z * e2y
    ny = e1z * e2x - e1x * e2z
    nz = e1x * e2y - e1y * e2x
    if det == 0.0 or not math.isfinite(det):
        return math.inf, nx, ny, nz
    inv = 1.0 / det
    tx = ox - ax
    ty = oy - ay
    tz = oz - az
    u = (tx * px + ty * py + tz * pz) * inv
    tol = 1e-9  # the two triangles of a cell and the neighbouring cells overlap by this much: no pinholes
    if u < -tol or u > 1.0 + tol:
        return math.inf, nx, ny, nz
    qx = ty * e1z - tz * e1y
    qy = tz * e1x - tx * e1z
    qz = tx * e1y - ty * e1x
    v = (dx * qx + dy * qy + dz * qz) * inv
    if v < -tol or u + v > 1.0 + tol:
        return math.inf, nx, ny, nz
    return (e2x * qx + e2y * qy + e2z * qz) * inv, nx, ny, nz


@numba.njit(cache=True)
def _hit_field(prim: np.ndarray, fields: np.ndarray, flags: np.ndarray, ox: float, oy: float, oz: float,
               dx: float, dy: float, dz: float, t_max: float
               ) -> tuple[float, float, float, int, float, float, float]:
    """Nearest hit of a ray with an RGB-D surface (a triangulated height field), exactly.

    The ray is moved into the source camera's frame (p' = Rᵀ(p − origin)/scale; the ray parameter is
    unchanged) and clipped to the slab zmin ≤ z ≤ zmax of the depths and to the pixel grid's frustum
    0 ≤ u ≤ W − 1, 0 ≤ v ≤ H − 1. Every triangle of cell (i, j) projects into the square [i, i+1]×[j, j+1]
    (its vertices project onto the grid points and a flat triangle projects onto the triangle of its
    projected vertices), and the clipped ray projects onto a segment traversed in order of increasing ray
    parameter, so walking the segment's cells (2-D DDA) and testing their two triangles finds the nearest hit.

    Returns
    -------
    t (inf if none), u, v (hit's projection into the source image, px), unknown (1 = no ground truth),
    normal (world, unnormalised).
    """
    c0 = prim[1]
    c1 = prim[2]
    c2 = prim[3]
    sc = prim[13]
    rx = ox - c0
    ry = oy - c1
    rz = oz - c2
    lox = (rx * prim[4] + ry * prim[5] + rz * prim[6]) / sc
    loy = (rx * prim[7] + ry * prim[8] + rz * prim[9]) / sc
    loz = (rx * prim[10] + ry * prim[11] + rz * prim[12]) / sc
    ldx = (dx * prim[4] + dy * prim[5] + dz * prim[6]) / sc
    ldy = (dx * prim[7] + dy * prim[8] + dz * prim[9]) / sc
    ldz = (dx * prim[10] + dy * prim[11] + dz * prim[12]) / sc
    w = np.int64(prim[22])
    h = np.int64(prim[23])
    fx = prim[24]
    fy = prim[25]
    cx = prim[26]
    cy = prim[27]
    off = np.int64(prim[28])
    zmin = prim[29]
    zmax = prim[30]
    foff = np.int64(prim[31])
    lo = 1e-9
    hi = t_max
    lo, hi = _clip(loz - zmin * (1.0 - 1e-12), ldz, lo, hi)
    lo, hi = _clip(zmax * (1.0 + 1e-12) - loz, -ldz, lo, hi)
    lo, hi = _clip(fx * lox - (0.0 - cx) * loz, fx * ldx - (0.0 - cx) * ldz, lo, hi)
    lo, hi = _clip((w - 1.0 - cx) * loz - fx * lox, (w - 1.0 - cx) * ldz - fx * ldx, lo, hi)
    lo, hi = _clip(fy * loy - (0.0 - cy) * loz, fy * ldy - (0.0 - cy) * ldz, lo, hi)
    lo, hi = _clip((h - 1.0 - cy) * loz - fy * loy, (h - 1.0 - cy) * ldz - fy * ldy, lo, hi)
    if not hi >= lo or not math.isfinite(hi):
        return math.inf, 0.0, 0.0, 0, 0.0, 0.0, 0.0
    za = loz + lo * ldz
    zb = loz + hi * ldz
    u0 = min(w - 1.0, max(0.0, fx * (lox + lo * ldx) / za + cx))
    v0 = min(h - 1.0, max(0.0, fy * (loy + lo * ldy) / za + cy))
    u1 = min(w - 1.0, max(0.0, fx * (lox + hi * ldx) / zb + cx))
    v1 = min(h - 1.0, max(0.0, fy * (loy + hi * ldy) / zb + cy))
    du = u1 - u0
    dv = v1 - v0
    i = min(np.int64(math.floor(u0)), w - 2)
    j = min(np.int64(math.floor(v0)), h - 2)
    si = 1 if du > 0.0 else -1
    sj = 1 if dv > 0.0 else -1
    if du != 0.0:
        tmu = ((i + 1.0 if du > 0.0 else float(i)) - u0) / du
        tdu = 1.0 / abs(du)
    else:
        tmu = math.inf
        tdu = math.inf
    if dv != 0.0:
        tmv = ((j + 1.0 if dv > 0.0 else float(j)) - v0) / dv
        tdv = 1.0 / abs(dv)
    else:
        tmv = math.inf
        tdv = math.inf
    best = math.inf
    bnx = 0.0
    bny = 0.0
    bnz = 0.0
    bunk = 0
    for _ in range(2 * (w + h) + 4):
        if i < 0 or j < 0 or i > w - 2 or j > h - 2:
            break
        k = off + j * w + i
        z00 = fields[k]
        z10 = fields[k + 1]
        z01 = fields[k + w]
        z11 = fields[k + w + 1]
        xa = (i - cx) / fx
        xb = (i + 1.0 - cx) / fx
        ya = (j - cy) / fy
        yb = (j + 1.0 - cy) / fy
        fl = flags[foff + j * (w - 1) + i]
        for tri in range(2):  # the cell's two triangles: (00, 10, 11) and (00, 11, 01); flag bit `tri`
            if tri == 0:
                z_b, u_b, v_b, z_c, u_c, v_c = z10, xb, ya, z11, xb, yb
            else:
                z_b, u_b, v_b, z_c, u_c, v_c = z11, xb, yb, z01, xa, yb
            t, nx, ny, nz = _triangle(lox, loy, loz, ldx, ldy, ldz, xa * z00, ya * z00, z00,
                                      u_b * z_b, v_b * z_b, z_b, u_c * z_c, v_c * z_c, z_c)
            if t > 1e-9 and t < best and t < t_max:
                best = t
                bnx = nx
                bny = ny
                bnz = nz
                bunk = (fl >> tri) & 1
        if best < math.inf or min(tmu, tmv) > 1.0:
            break
        if tmu < tmv:
            i += si
            tmu += tdu
        else:
            j += sj
            tmv += tdv
    if best == math.inf:
        return math.inf, 0.0, 0.0, 0, 0.0, 0.0, 0.0
    px = lox + best * ldx
    py = loy + best * ldy
    pz = loz + best * ldz
    hu = fx * px / pz + cx
    hv = fy * py / pz + cy
    wnx = bnx * prim[4] + bny * prim[7] + bnz * prim[10]
    wny = bnx * prim[5] + bny * prim[8] + bnz * prim[11]
    wnz = bnx * prim[6] + bny * prim[9] + bnz * prim[12]
    return best, hu, hv, bunk, wnx, wny, wnz


@numba.njit(cache=True, parallel=True, nogil=True)
def trace_scene_kernel(origins: np.ndarray, directions: np.ndarray, prims: np.ndarray, textures: np.ndarray,
                       pixels: np.ndarray, fields: np.ndarray, flags: np.ndarray, shading: float,
                       light: np.ndarray, distance: np.ndarray, object_id: np.ndarray, points: np.ndarray,
                       colors: np.ndarray) -> None:
    """Nearest hit of each ray with the primitives, its point, object id and shaded colour.

    Parameters
    ----------
    origins, directions : (N, 3) float64; rows with NaN are skipped (no hit).
    prims, textures, pixels, fields, flags : arrays of :class:`CompiledScene`.
    shading : float in [0, 1]; light : (3,) unit direction toward the light.
    distance : (N,) float64 out: ray parameter times |d| (mm along the ray), NaN if no hit.
    object_id : (N,) int32 out: −1 if no hit.
    points : (N, 3) float64 out (NaN if no hit, and where an RGB-D surface has no ground truth);
    colors : (N, 3) float32 out (NaN if no hit).
    """
    n = origins.shape[0]
    n_prims = prims.shape[0]
    for r in numba.prange(n):
        ox = origins[r, 0]
        oy = origins[r, 1]
        oz = origins[r, 2]
        dx = directions[r, 0]
        dy = directions[r, 1]
        dz = directions[r, 2]
        best_t = np.inf
        best_p = -1
        fu = 0.0
        fv = 0.0
        funk = 0
        fnx = 0.0
        fny = 0.0
        fnz = 0.0
        if math.isfinite(ox + oy + oz + dx + dy + dz):
            dd = dx * dx + dy * dy + dz * dz
            p = -1
            while p + 1 < n_prims:
                p += 1
                kind = prims[p, 0]
                if kind == 4:
                    th, hu, hv, hunk, hnx, hny, hnz = _hit_field(prims[p], fields, flags, ox, oy, oz, dx, dy, dz,
                                                                 best_t)
                    if th < best_t:
                        best_t = th
                        best_p = p
                        fu = hu
                        fv = hv
                        funk = hunk
                        fnx = hnx
                        fny = hny
                        fnz = hnz
                    continue
                cx = prims[p, 1] - ox
                cy = prims[p, 2] - oy
                cz = prims[p, 3] - oz
                if kind == 3:
                    # bounding sphere: skip the guarded primitives unless the ray meets it before best_t
                    b = dx * cx + dy * cy + dz * cz
                    cc = cx * cx + cy * cy + cz * cz - prims[p, 13] * prims[p, 13]
                    disc = b * b - dd * cc
                    if disc < 0.0 or (b + math.sqrt(disc)) <= 0.0 or (b - math.sqrt(disc)) / dd >= best_t:
                        p += int(prims[p, 14])
                    continue
                if kind == 1:
                    # |o + t d − c|² = R²  with  w = c − o
                    b = dx * cx + dy * cy + dz * cz
                    cc = cx * cx + cy * cy + cz * cz - prims[p, 13] * prims[p, 13]
                    disc = b * b - dd * cc
                    if disc < 0.0:
                        continue
                    sq = math.sqrt(disc)
                    t = (b - sq) / dd
                    if t <= 1e-9:
                        t = (b + sq) / dd
                    if t <= 1e-9 or t >= best_t:
                        continue
                else:
                    denom = dx * prims[p, 10] + dy * prims[p, 11] + dz * prims[p, 12]
                    if abs(denom) < 1e-15:
                        continue
                    t = (cx * prims[p, 10] + cy * prims[p, 11] + cz * prims[p, 12]) / denom
                    if t <= 1e-9 or t >= best_t:
                        continue
                    if kind == 0:
                        qx = t * dx - cx
                        qy = t * dy - cy
                        qz = t * dz - cz
                        u = qx * prims[p, 4] + qy * prims[p, 5] + qz * prims[p, 6]
                        if abs(u) > prims[p, 13]:
                            continue
                        v = qx * prims[p, 7] + qy * prims[p, 8] + qz * prims[p, 9]
                        if abs(v) > prims[p, 14]:
                            continue
                best_t = t
                best_p = p
        if best_p < 0:
            distance[r] = np.nan
            object_id[r] = -1
            for k in range(3):
                points[r, k] = np.nan
                colors[r, k] = np.nan
            continue
        p = best_p
        px = ox + best_t * dx
        py = oy + best_t * dy
        pz = oz + best_t * dz
        distance[r] = best_t * math.sqrt(dd)
        object_id[r] = np.int32(prims[p, 16])
        if funk and prims[p, 0] == 4:
            points[r, 0] = np.nan
            points[r, 1] = np.nan
            points[r, 2] = np.nan
        else:
            points[r, 0] = px
            points[r, 1] = py
            points[r, 2] = pz
        qx = px - prims[p, 1]
        qy = py - prims[p, 2]
        qz = pz - prims[p, 3]
        u = qx * prims[p, 4] + qy * prims[p, 5] + qz * prims[p, 6]
        v = qx * prims[p, 7] + qy * prims[p, 8] + qz * prims[p, 9]
        kind = prims[p, 0]
        if kind == 4:
            s = fu + 0.5
            tt = fv + 0.5
            nn = math.sqrt(fnx * fnx + fny * fny + fnz * fnz)
            nx = fnx / nn if nn > 0.0 else 0.0
            ny = fny / nn if nn > 0.0 else 0.0
            nz = fnz / nn if nn > 0.0 else 0.0
            if nx * dx + ny * dy + nz * dz > 0.0:
                nx = -nx
                ny = -ny
                nz = -nz
        elif kind == 1:
            w = qx * prims[p, 10] + qy * prims[p, 11] + qz * prims[p, 12]
            rad = prims[p, 13]
            s = rad * (math.atan2(u, -w) + math.pi)
            tt = rad * math.acos(min(1.0, max(-1.0, (v / rad))))
            nx = qx / rad
            ny = qy / rad
            nz = qz / rad
        else:
            s = u + prims[p, 20]
            tt = v + prims[p, 21]
            nx = prims[p, 10]
            ny = prims[p, 11]
            nz = prims[p, 12]
            if nx * dx + ny * dy + nz * dz > 0.0:
                nx = -nx
                ny = -ny
                nz = -nz
        cr, cg, cb = _texture(textures[np.int64(prims[p, 15])], pixels, s, tt, prims[p, 18], prims[p, 19],
                              int(prims[p, 17]))
        f = 1.0
        if shading > 0.0:
            lam = max(0.0, nx * light[0] + ny * light[1] + nz * light[2])
            f = 1.0 - shading + shading * lam
        colors[r, 0] = np.float32(cr * f)
        colors[r, 1] = np.float32(cg * f)
        colors[r, 2] = np.float32(cb * f)


@numba.njit(cache=True, parallel=True, nogil=True)
def average_samples_kernel(colors: np.ndarray, valid: np.ndarray, n_samples: int, background: np.ndarray,
                           out: np.ndarray) -> None:
    """Average the colours of each pixel's valid samples.

    Parameters
    ----------
    colors : (P·S, 3) float32, NaN rows = valid ray that hit nothing (→ ``background``).
    valid : (P·S,) bool, False = the ray did not pass the prism (excluded).
    n_samples : S.
    background : (3,) float32.
    out : (P, 3) float32 out; black where no sample is valid.
    """
    n_pix = out.shape[0]
    for i in numba.prange(n_pix):
        r = 0.0
        g = 0.0
        b = 0.0
        cnt = 0
        for k in range(i * n_samples, (i + 1) * n_samples):
            if not valid[k]:
                continue
            cnt += 1
            if math.isnan(colors[k, 0]):
                r += background[0]
                g += background[1]
                b += background[2]
            else:
                r += colors[k, 0]
                g += colors[k, 1]
                b += colors[k, 2]
        if cnt == 0:
            out[i, 0] = 0.0
            out[i, 1] = 0.0
            out[i, 2] = 0.0
        else:
            out[i, 0] = r / cnt
            out[i, 1] = g / cnt
            out[i, 2] = b / cnt
