"""Scene files: a rig (docs/rig.md [camera] and [prism]) plus ``[render]`` and ``[[objects]]`` tables.

Example::

    [camera]
    width = 1024
    height = 768
    focal_length = 25.0
    pixel_size = 0.00465

    [prism]
    faces = 2
    corner_angle = 6.4
    refractive_index = 1.5
    apex_distance = 210.0
    back_distance = 215.6

    [render]                      # every key optional
    supersample = 2               # samples per pixel side (1..16)
    seed = 0                      # sensor-noise seed; default seed of noise textures (seed + object index)
    background = [0.0, 0.0, 0.0]  # RGB in [0, 1] of rays that pass the prism and hit nothing
    shading = 0.3                 # Lambertian light strength in [0, 1] (view-independent)
    noise = 0.0                   # sensor noise std, grey levels (the capture is rounded to 8 bits after it)
    vignetting = 0.0              # fraction of light lost at the image corners, [0, 0.99]
    # abbe = 64.2                 # Abbe number of the glass: per-channel index, colour fringes (default none)
    # bayer = "RGGB"              # colour filter mosaic (RGGB, BGGR, GRBG, GBRG), noise per recorded channel,
    # demosaic = "edge-aware"     #   then demosaiced: "bilinear" | "edge-aware" | "vng" (default none)
    # jpeg_quality = 85           # saved as JPEG of this quality and decoded (default lossless)

    # [lens]                      # a thin lens (default: a pinhole), docs/scenes.md
    # f_number = 8.0
    # focus_distance = 1400.0     # mm along the axis
    # samples = 16                # aperture rays per pixel

    [[objects]]
    type = "box"                  # "rectangle" | "box" | "sphere" | "plane" | "rgbd" (below)
    name = "torso"                # optional
    center = [0.0, 0.0, 1500.0]   # mm, world frame (+X right, +Y down, +Z forward)
    size = [60.0, 80.0, 40.0]     # rectangle: [w, h]; box: [sx, sy, sz]; sphere: radius = R instead
    rotation = [0.0, 25.0, 0.0]   # extrinsic XYZ Euler angles, degrees (optional) ...
    # normal = [0.0, 0.0, -1.0]   # ... or the direction the front faces, with optional spin = degrees
    [objects.texture]
    type = "noise"                # "noise" | "checker" | "image" | "solid"
    scale = 30.0                  # mm, coarsest feature; octaves = 6, persistence = 0.8, contrast = 2.5, seed
    # checker: square = 10.0, colors = [[0,0,0],[1,1,1]], squares = [9, 7], margin = 10.0, border_color
    # image:   path = "textures/robot.png" (relative to the scene file), size = [w_mm, h_mm] (optional)
    # solid:   color = [0.8, 0.2, 0.1]

    [[objects]]                   # a photographed scene: colour + depth, a height field (simulate/rgbd.py)
    type = "rgbd"
    color = "im0.png"             # the colour image (relative to the scene file)
    disparity = "disp0GT.pfm"     # ... with baseline (mm), doffs (px, default 0), disparity_scale (value / it)
    baseline = 193.0              #     Z = baseline · focal_px / (d + doffs); PNG 0 / PFM inf = unknown
    doffs = 124.3
    # depth = "depth.pfm"         # ... or depth in mm (PFM, or a PNG with depth_scale mm per unit)
    focal_px = 3997.7             # the colour camera's focal length, px (or [fx, fy])
    # principal_point = [1176.7, 1011.3]   # px; default the image centre
    center_depth = 1400.0         # mm: world Z of the scene's median depth, facing the camera ...
    width = 120.0                 # mm: the photograph's field at that depth (or scale = s; default: the
                                  #     source camera at the camera centre, scale = center_depth / median)
    # origin = [0, 0, 500]        # ... or the source camera's centre (mm) with rotation/normal and scale
    # jump = 0.02                 # relative depth spread above which a triangle is skin (no ground truth)
    # middlebury = "../shared/data/middlebury-2014/Piano"  # instead of color ... principal_point: a folder

Everything is validated before rendering; problems raise :class:`~prismstereo.errors.ConfigError` with
one line naming the table and key.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import tomli_w

from prismstereo.config import Rig, read_toml, rig_from_dict
from prismstereo.errors import ConfigError, ImageError
from prismstereo.io import read_image
from prismstereo.simulate.rgbd import depth_from_disparity, middlebury_rgbd, read_depth_map, read_disparity_map
from prismstereo.simulate.scene import (
    BAYER_PATTERNS,
    DEMOSAIC_METHODS,
    Box,
    CheckerTexture,
    Color,
    ImageTexture,
    NoiseTexture,
    Plane,
    Rectangle,
    RGBDSurface,
    Scene,
    SceneObject,
    SolidTexture,
    Sphere,
    Texture,
    ThinLens,
    Vec3,
    rotation_from_normal,
)

_RENDER_KEYS = {"supersample", "seed", "background", "shading", "noise", "vignetting", "abbe", "bayer", "demosaic",
                "jpeg_quality"}
_LENS_KEYS = {"f_number", "focus_distance", "samples"}
_OBJECT_KEYS = {
    "rectangle": {"type", "name", "center", "size", "rotation", "normal", "spin", "texture"},
    "box": {"type", "name", "center", "size", "rotation", "normal", "spin", "texture"},
    "sphere": {"type", "name", "center", "radius", "rotation", "normal", "spin", "texture"},
    "plane": {"type", "name", "center", "rotation", "normal", "spin", "texture"},
    "rgbd": {"type", "name", "color", "depth", "depth_scale", "disparity", "disparity_scale", "baseline", "doffs",
             "focal_px", "principal_point", "middlebury", "center_depth", "scale", "width", "origin", "rotation",
             "normal", "spin", "jump"},
}
_TEXTURE_KEYS = {
    "solid": {"type", "color"},
    "checker": {"type", "square", "colors", "squares", "margin", "border_color"},
    "noise": {"type", "scale", "octaves", "persistence", "contrast", "seed"},
    "image": {"type", "path", "size"},
}


# --------------------------------------------------------------------------- checked readers
def _is_num(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _num(where: str, key: str, v: Any, *, positive: bool = False, lo: float | None = None,
         hi: float | None = None) -> float:
    if not _is_num(v) or not math.isfinite(float(v)):
        raise ConfigError(f"{where} {key}: expected a finite number, got {v!r}")
    x = float(v)
    if positive and x <= 0:
        raise ConfigError(f"{where} {key}: expected a positive number, got {v!r}")
    if (lo is not None and x < lo) or (hi is not None and x > hi):
        raise ConfigError(f"{where} {key}: expected a number in [{lo:g}, {hi:g}], got {v!r}")
    return x


def _int(where: str, key: str, v: Any, *, lo: int | None = None, hi: int | None = None) -> int:
    if isinstance(v, bool) or not isinstance(v, int):
        raise ConfigError(f"{where} {key}: expected an integer, got {v!r}")
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        rng = f">= {lo}" if hi is None else f"in {lo}..{hi}"
        raise ConfigError(f"{where} {key}: expected an integer {rng}, got {v!r}")
    return int(v)


def _vec(where: str, key: str, v: Any, n: int, *, positive: bool = False) -> tuple[float, ...]:
    what = f"{n} positive numbers" if positive else f"{n} finite numbers"
    if not isinstance(v, list | tuple) or len(v) != n or not all(_is_num(x) for x in v):
        raise ConfigError(f"{where} {key}: expected a list of {what}, got {v!r}")
    out = tuple(float(x) for x in v)
    if not all(math.isfinite(x) for x in out) or (positive and not all(x > 0 for x in out)):
        raise ConfigError(f"{where} {key}: expected a list of {what}, got {v!r}")
    return out


def _color(where: str, key: str, v: Any) -> Color:
    c = _vec(where, key, v, 3)
    if not all(0.0 <= x <= 1.0 for x in c):
        raise ConfigError(f"{where} {key}: expected an RGB colour [r, g, b] with values in [0, 1], got {v!r}")
    return (c[0], c[1], c[2])


def _keys(where: str, table: Any, allowed: set[str], required: set[str] | None = None) -> Mapping[str, Any]:
    if not isinstance(table, Mapping):
        raise ConfigError(f"{where}: expected a table, got {table!r}")
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {', '.join(unknown)}; expected only {', '.join(sorted(allowed))}")
    missing = sorted((required or set()) - set(table))
    if missing:
        raise ConfigError(f"{where}: missing key(s) {', '.join(missing)}")
    return table


# --------------------------------------------------------------------------- parsing
def _texture(where: str, t: Any, *, default_seed: int, base_dir: Path, obj_type: str) -> Texture:
    if t is None:
        return NoiseTexture(seed=default_seed)
    if not isinstance(t, Mapping):
        raise ConfigError(f"{where}: expected a table, got {t!r}")
    kind = t.get("type")
    if kind not in _TEXTURE_KEYS:
        raise ConfigError(f"{where} type: expected one of {', '.join(sorted(_TEXTURE_KEYS))}, got {kind!r}")
    required = {"solid": {"color"}, "checker": {"square"}, "noise": set(), "image": {"path"}}[kind]
    _keys(where, t, _TEXTURE_KEYS[kind], required | {"type"})
    if kind == "solid":
        return SolidTexture(color=_color(where, "color", t["color"]))
    if kind == "checker":
        colors = t.get("colors", [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])
        if not isinstance(colors, list | tuple) or len(colors) != 2:
            raise ConfigError(f"{where} colors: expected two RGB colours [[r,g,b],[r,g,b]], got {colors!r}")
        squares = t.get("squares")
        sq: tuple[int, int] | None = None
        if squares is not None:
            if not isinstance(squares, list | tuple) or len(squares) != 2:
                raise ConfigError(f"{where} squares: expected [nx, ny] (integers >= 2), got {squares!r}")
            sq = (_int(where, "squares", squares[0], lo=2), _int(where, "squares", squares[1], lo=2))
        return CheckerTexture(
            square=_num(where, "square", t["square"], positive=True),
            colors=(_color(where, "colors", colors[0]), _color(where, "colors", colors[1])),
            squares=sq,
            margin=_num(where, "margin", t.get("margin", 0.0), lo=0.0, hi=math.inf),
            border_color=_color(where, "border_color", t.get("border_color", [1.0, 1.0, 1.0])),
        )
    if kind == "noise":
        return NoiseTexture(
            scale=_num(where, "scale", t.get("scale", 50.0), positive=True),
            octaves=_int(where, "octaves", t.get("octaves", 6), lo=1, hi=16),
            persistence=_num(where, "persistence", t.get("persistence", 0.8), lo=0.0, hi=1.0),
            contrast=_num(where, "contrast", t.get("contrast", 2.5), positive=True),
            seed=_int(where, "seed", t.get("seed", default_seed), lo=0),
        )
    # image
    path = t["path"]
    if not isinstance(path, str) or not path:
        raise ConfigError(f"{where} path: expected an image file name, got {path!r}")
    full = Path(path) if os.path.isabs(path) else base_dir / path
    try:
        img = read_image(full)
    except ImageError as exc:
        raise ConfigError(f"{where} path: {exc}") from None
    size = t.get("size")
    if size is None and obj_type == "plane":
        raise ConfigError(f"{where} size: expected [w, h] in mm for an image on an infinite plane, got none")
    sz = None if size is None else _vec(where, "size", size, 2, positive=True)
    return ImageTexture(path=str(full.resolve()), image=img, size=None if sz is None else (sz[0], sz[1]))


def _path(where: str, key: str, v: Any, base_dir: Path) -> Path:
    if not isinstance(v, str) or not v:
        raise ConfigError(f"{where} {key}: expected a file name, got {v!r}")
    p = Path(v) if os.path.isabs(v) else base_dir / v
    if not p.exists():
        raise ConfigError(f"{where} {key}: expected an existing file, got {str(p)!r} (no such file)")
    return p


def _rotation(where: str, o: Mapping[str, Any]) -> Vec3:
    if "rotation" in o and ("normal" in o or "spin" in o):
        raise ConfigError(f"{where}: expected either rotation or normal (+ spin), got both")
    if "rotation" in o:
        r = _vec(where, "rotation", o["rotation"], 3)
        return (r[0], r[1], r[2])
    normal = _vec(where, "normal", o.get("normal", [0.0, 0.0, -1.0]), 3)
    if math.hypot(*normal) < 1e-12:
        raise ConfigError(f"{where} normal: expected a non-zero vector, got {list(normal)}")
    return rotation_from_normal((normal[0], normal[1], normal[2]), spin=_num(where, "spin", o.get("spin", 0.0)))


def _rgbd_object(where: str, o: Mapping[str, Any], name: str, base_dir: Path) -> RGBDSurface:
    """An ``rgbd`` object: colour + depth (or disparity + calibration), intrinsics, pose and scale."""
    jump = _num(where, "jump", o.get("jump", 0.02), positive=True)
    placed = "center_depth" in o
    if placed == ("origin" in o):
        raise ConfigError(f"{where}: expected center_depth (with scale or width) or origin (with rotation or "
                          f"normal, and scale), got {'both' if placed else 'neither'}")
    if placed and ({"rotation", "normal", "spin"} & set(o)):
        raise ConfigError(f"{where}: rotation/normal/spin go with origin; center_depth places the scene facing "
                          f"the camera")
    if "scale" in o and "width" in o:
        raise ConfigError(f"{where}: expected scale or width, got both")
    if "width" in o and not placed:
        raise ConfigError(f"{where} width: goes with center_depth; with origin give scale")
    scale = None if "scale" not in o else _num(where, "scale", o["scale"], positive=True)
    width = None if "width" not in o else _num(where, "width", o["width"], positive=True)
    if "middlebury" in o:
        clash = sorted({"color", "depth", "disparity", "depth_scale", "disparity_scale", "baseline", "doffs",
                        "focal_px", "principal_point"} & set(o))
        if clash:
            raise ConfigError(f"{where}: middlebury reads the folder's own files and calibration; remove "
                              f"{', '.join(clash)}")
        if not placed:
            raise ConfigError(f"{where}: middlebury goes with center_depth (and scale or width)")
        folder = _path(where, "middlebury", o["middlebury"], base_dir)
        surf = middlebury_rgbd(folder, center_depth=_num(where, "center_depth", o["center_depth"], positive=True),
                               scale=scale, width=width, jump=jump)
        return RGBDSurface(image=surf.image, depth=surf.depth, focal=surf.focal,
                           principal_point=surf.principal_point, origin=surf.origin, rotation=surf.rotation,
                           scale=surf.scale, jump=surf.jump, name=name, source=surf.source)
    if "color" not in o:
        raise ConfigError(f"{where}: missing key color (the colour image)")
    if ("depth" in o) == ("disparity" in o):
        raise ConfigError(f"{where}: expected depth (mm) or disparity (px, with baseline and focal_px), got "
                          f"{'both' if 'depth' in o else 'neither'}")
    if "focal_px" not in o:
        raise ConfigError(f"{where}: missing key focal_px (the colour camera's focal length, px)")
    fv = o["focal_px"]
    if isinstance(fv, list | tuple):
        f2 = _vec(where, "focal_px", fv, 2, positive=True)
        focal = (f2[0], f2[1])
    else:
        f1 = _num(where, "focal_px", fv, positive=True)
        focal = (f1, f1)
    pp = None
    if "principal_point" in o:
        c2 = _vec(where, "principal_point", o["principal_point"], 2)
        pp = (c2[0], c2[1])
    color_path = _path(where, "color", o["color"], base_dir)
    try:
        image = read_image(color_path)
    except ImageError as exc:
        raise ConfigError(f"{where} color: {exc}") from None
    source: dict[str, Any] = {"color": str(color_path.resolve())}
    if "depth" in o:
        extra = sorted({"disparity_scale", "baseline", "doffs"} & set(o))
        if extra:
            raise ConfigError(f"{where}: {', '.join(extra)} go(es) with disparity, not depth")
        dscale = _num(where, "depth_scale", o.get("depth_scale", 1.0), positive=True)
        dpath = _path(where, "depth", o["depth"], base_dir)
        depth = read_depth_map(dpath, scale=dscale)
        source.update(depth=str(dpath.resolve()), depth_scale=dscale)
    else:
        if "depth_scale" in o:
            raise ConfigError(f"{where}: depth_scale goes with depth, not disparity (use disparity_scale)")
        if "baseline" not in o:
            raise ConfigError(f"{where}: missing key baseline (mm) to turn the disparity into depth")
        baseline = _num(where, "baseline", o["baseline"], positive=True)
        doffs = _num(where, "doffs", o.get("doffs", 0.0))
        pscale = _num(where, "disparity_scale", o.get("disparity_scale", 1.0), positive=True)
        dpath = _path(where, "disparity", o["disparity"], base_dir)
        depth = depth_from_disparity(read_disparity_map(dpath, scale=pscale), focal_px=focal[0],
                                     baseline_mm=baseline, doffs_px=doffs)
        source.update(disparity=str(dpath.resolve()), disparity_scale=pscale, baseline=baseline, doffs=doffs)
    if depth.shape != image.shape[:2]:
        raise ConfigError(f"{where}: expected the depth/disparity map at the colour image's size "
                          f"{image.shape[1]}×{image.shape[0]}, got {depth.shape[1]}×{depth.shape[0]}")
    if placed:
        return RGBDSurface.placed(image, depth, focal=focal, principal_point=pp,
                                  center_depth=_num(where, "center_depth", o["center_depth"], positive=True),
                                  scale=scale, width=width, jump=jump, name=name, source=source)
    org = _vec(where, "origin", o["origin"], 3)
    return RGBDSurface(image=image, depth=depth, focal=focal, principal_point=pp, origin=(org[0], org[1], org[2]),
                       rotation=_rotation(where, o), scale=1.0 if scale is None else scale, jump=jump, name=name,
                       source=source)


def _object(i: int, o: Any, *, seed: int, base_dir: Path) -> SceneObject:
    where = f"[[objects]] #{i}"
    if not isinstance(o, Mapping):
        raise ConfigError(f"{where}: expected a table, got {o!r}")
    kind = o.get("type")
    if kind not in _OBJECT_KEYS:
        raise ConfigError(f"{where} type: expected one of {', '.join(sorted(_OBJECT_KEYS))}, got {kind!r}")
    name = o.get("name", f"{kind}{i}")
    if not isinstance(name, str):
        raise ConfigError(f"{where} name: expected a string, got {name!r}")
    where = f"[[objects]] #{i} ({kind} {name!r})"
    if kind == "rgbd":
        _keys(where, o, _OBJECT_KEYS[kind], {"type"})
        return _rgbd_object(where, o, name, Path(base_dir))
    required = {"type", "center"} | {"rectangle": {"size"}, "box": {"size"}, "sphere": {"radius"}, "plane": set()}[kind]
    _keys(where, o, _OBJECT_KEYS[kind], required)
    c = _vec(where, "center", o["center"], 3)
    center: Vec3 = (c[0], c[1], c[2])
    if "rotation" in o and ("normal" in o or "spin" in o):
        raise ConfigError(f"{where}: expected either rotation or normal (+ spin), got both")
    if "rotation" in o:
        r = _vec(where, "rotation", o["rotation"], 3)
        rotation: Vec3 = (r[0], r[1], r[2])
    else:
        normal = _vec(where, "normal", o.get("normal", [0.0, 0.0, -1.0]), 3)
        if math.hypot(*normal) < 1e-12:
            raise ConfigError(f"{where} normal: expected a non-zero vector, got {list(normal)}")
        rotation = rotation_from_normal((normal[0], normal[1], normal[2]), spin=_num(where, "spin", o.get("spin", 0.0)))
    texture = _texture(f"{where} texture", o.get("texture"), default_seed=seed + i, base_dir=base_dir,
                       obj_type=kind)
    if kind == "rectangle":
        s = _vec(where, "size", o["size"], 2, positive=True)
        return Rectangle(center=center, size=(s[0], s[1]), rotation=rotation, texture=texture, name=name)
    if kind == "box":
        s = _vec(where, "size", o["size"], 3, positive=True)
        return Box(center=center, size=(s[0], s[1], s[2]), rotation=rotation, texture=texture, name=name)
    if kind == "sphere":
        rad = _num(where, "radius", o["radius"], positive=True)
        return Sphere(center=center, radius=rad, rotation=rotation, texture=texture, name=name)
    return Plane(center=center, rotation=rotation, texture=texture, name=name)


def scene_from_dict(data: Mapping[str, Any], *, base_dir: str | os.PathLike[str] = ".",
                    name: str = "scene") -> tuple[Rig, Scene]:
    """Validate a parsed scene file and build its rig and scene.

    Parameters
    ----------
    data : mapping
        Parsed TOML: [camera], [prism], optional [render], [[objects]].
    base_dir : path
        Folder that relative image-texture paths are resolved against (the scene file's folder).

    Returns
    -------
    (Rig, Scene)

    Raises
    ------
    ConfigError
        On unknown tables/keys/types, missing keys, non-positive sizes, NaN or out-of-range values.
    """
    rig = rig_from_dict(data, name=name, extra_sections={"render", "objects", "lens"})
    render = _keys("[render]", data.get("render", {}), _RENDER_KEYS)
    seed = _int("[render]", "seed", render.get("seed", 0), lo=0)
    ss = _int("[render]", "supersample", render.get("supersample", 2), lo=1, hi=16)
    background = _color("[render]", "background", render.get("background", [0.0, 0.0, 0.0]))
    shading = _num("[render]", "shading", render.get("shading", 0.0), lo=0.0, hi=1.0)
    noise = _num("[render]", "noise", render.get("noise", 0.0), lo=0.0, hi=255.0)
    vignetting = _num("[render]", "vignetting", render.get("vignetting", 0.0), lo=0.0, hi=0.99)
    abbe = None if "abbe" not in render else _num("[render]", "abbe", render["abbe"], lo=10.0, hi=120.0)
    bayer = render.get("bayer")
    if bayer is not None and bayer not in BAYER_PATTERNS:
        raise ConfigError(f"[render] bayer: expected one of {', '.join(BAYER_PATTERNS)}, got {bayer!r}")
    demosaic = render.get("demosaic", "edge-aware")
    if demosaic not in DEMOSAIC_METHODS:
        raise ConfigError(f"[render] demosaic: expected one of {', '.join(DEMOSAIC_METHODS)}, got {demosaic!r}")
    if "demosaic" in render and bayer is None:
        raise ConfigError("[render] demosaic: goes with bayer (a colour filter mosaic), which is not set")
    jpeg = None if "jpeg_quality" not in render else _int("[render]", "jpeg_quality", render["jpeg_quality"],
                                                          lo=1, hi=100)
    lens = None
    if "lens" in data:
        lt = _keys("[lens]", data["lens"], _LENS_KEYS, {"f_number", "focus_distance"})
        lens = ThinLens(f_number=_num("[lens]", "f_number", lt["f_number"], lo=0.5, hi=1000.0),
                        focus_distance=_num("[lens]", "focus_distance", lt["focus_distance"], positive=True),
                        samples=_int("[lens]", "samples", lt.get("samples", 16), lo=1, hi=256))
    objs = data.get("objects", [])
    if not isinstance(objs, list) or not objs:
        raise ConfigError(f"[[objects]]: expected at least one [[objects]] table, got {objs!r}")
    base = Path(base_dir)
    objects = tuple(_object(i, o, seed=seed, base_dir=base) for i, o in enumerate(objs))
    scene = Scene(objects=objects, background=background, shading=shading, noise=noise, seed=seed,
                  supersample=ss, name=name, vignetting=vignetting, abbe=abbe, lens=lens, bayer=bayer,
                  demosaic=demosaic, jpeg_quality=jpeg)
    return rig, scene


def load_scene(path: str | os.PathLike[str]) -> tuple[Rig, Scene]:
    """Read and validate a scene TOML file → (Rig, Scene). Image paths are relative to the file."""
    p = Path(path)
    return scene_from_dict(read_toml(p), base_dir=p.parent, name=p.stem)


# --------------------------------------------------------------------------- writing
def _texture_dict(t: Texture) -> dict[str, Any]:
    if isinstance(t, SolidTexture):
        return {"type": "solid", "color": list(t.color)}
    if isinstance(t, CheckerTexture):
        d: dict[str, Any] = {"type": "checker", "square": t.square, "colors": [list(c) for c in t.colors],
                             "margin": t.margin, "border_color": list(t.border_color)}
        if t.squares is not None:
            d["squares"] = list(t.squares)
        return d
    if isinstance(t, NoiseTexture):
        return {"type": "noise", "scale": t.scale, "octaves": t.octaves, "persistence": t.persistence,
                "contrast": t.contrast, "seed": t.seed}
    d = {"type": "image", "path": t.path}
    if t.size is not None:
        d["size"] = list(t.size)
    return d


def object_to_dict(obj: SceneObject) -> dict[str, Any]:
    """The ``[[objects]]`` table of an object (resolved: rotation as Euler angles, full texture)."""
    if isinstance(obj, RGBDSurface):
        if "color" not in obj.source or not ({"depth", "disparity"} & set(obj.source)):
            raise ConfigError(f"rgbd object {obj.name!r}: expected the files it was read from (its source) to "
                              f"write a scene file, got none; build it from files (scene TOML or middlebury_rgbd)")
        r: dict[str, Any] = {"type": "rgbd", "name": obj.name, **obj.source, "focal_px": list(obj.focal)}
        if obj.principal_point is not None:
            r["principal_point"] = list(obj.principal_point)
        r.update(origin=list(obj.origin), rotation=list(obj.rotation), scale=obj.scale, jump=obj.jump)
        return r
    kind = {Rectangle: "rectangle", Box: "box", Sphere: "sphere", Plane: "plane"}[type(obj)]
    d: dict[str, Any] = {"type": kind, "name": obj.name, "center": list(obj.center)}
    if isinstance(obj, Rectangle | Box):
        d["size"] = list(obj.size)
    if isinstance(obj, Sphere):
        d["radius"] = obj.radius
    d["rotation"] = list(obj.rotation)
    d["texture"] = _texture_dict(obj.texture)
    return d


def scene_to_dict(rig: Rig, scene: Scene) -> dict[str, Any]:
    """The resolved scene file (every default filled in) as a TOML-ready mapping."""
    data = rig.to_dict()
    data["render"] = {"supersample": scene.supersample, "seed": scene.seed, "background": list(scene.background),
                      "shading": scene.shading, "noise": scene.noise, "vignetting": scene.vignetting}
    if scene.abbe is not None:
        data["render"]["abbe"] = scene.abbe
    if scene.bayer is not None:
        data["render"].update(bayer=scene.bayer, demosaic=scene.demosaic)
    if scene.jpeg_quality is not None:
        data["render"]["jpeg_quality"] = scene.jpeg_quality
    if scene.lens is not None:
        data["lens"] = {"f_number": scene.lens.f_number, "focus_distance": scene.lens.focus_distance,
                        "samples": scene.lens.samples}
    data["objects"] = [object_to_dict(o) for o in scene.objects]
    return data


def scene_to_toml(rig: Rig, scene: Scene) -> str:
    """TOML text of :func:`scene_to_dict`; it loads back to the same rig and scene."""
    return tomli_w.dumps(scene_to_dict(rig, scene))
