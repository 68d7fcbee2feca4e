"""The library in one call per task: :func:`load_rig`, :func:`depth`, :func:`simulate`, :func:`calibrate_prism`.

``import prismstereo`` gives these four (``prismstereo.depth(...)``, ...; docs/api.md). Each takes paths or
in-memory values, checks every option before any image is read or any heavy work starts (the configuration
first, then the inputs), and returns a result that holds the arrays and a ``save(folder)`` that writes
exactly the files of the matching command (``prismstereo depth``, ``simulate``, ``calibrate-prism``), all
of them or none. The commands in :mod:`prismstereo.apps` are thin callers of these functions.

Errors are the project's (:mod:`prismstereo.errors`) and name the parameter of these functions
(``views: ...``, ``DepthConfig.min_confidence: ...``); the command line maps the names to its flags.
"""

from __future__ import annotations

import dataclasses
import logging
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from prismstereo.calibration import Board, PrismCalibration, parse_board, parse_free
from prismstereo.calibration import calibrate_prism as fit_prism_to_boards
from prismstereo.calibration.from_scene import SceneCalibration, calibrate_from_scene, parse_scene_free
from prismstereo.calibration.report import residual_figure
from prismstereo.calibration.scene_uncertainty import uncertainty_warnings, unobserved_depth_error
from prismstereo.config import Rig, load_rig
from prismstereo.depth.memory import check_depth_memory
from prismstereo.depth.outputs import write_depth_outputs
from prismstereo.depth.pipeline import DepthConfig, DepthRun, run_depth, validate_config, validate_image
from prismstereo.depth.presets import apply_preset, preset_record
from prismstereo.errors import ConfigError, ImageError
from prismstereo.evaluation.depth_metrics import evaluate_depth, read_depth_gt
from prismstereo.io import (
    atomic_write_bytes,
    atomic_write_text,
    output_dir,
    read_image,
    write_image,
    write_json,
    write_pfm,
)
from prismstereo.io.memory import check_fits_in_memory
from prismstereo.simulate import robot_scene
from prismstereo.simulate.render import Capture, render_capture
from prismstereo.simulate.scene import Scene
from prismstereo.simulate.scene_toml import load_scene, scene_to_toml

log = logging.getLogger(__name__)

__all__ = ["DEPTH_OPTIONS", "SIMULATION_FILES", "Calibration", "DepthResult", "Simulation", "calibrate_prism",
           "depth", "depth_config", "load_rig", "simulate"]

#: the keyword options of :func:`depth`: the fields of :class:`~prismstereo.depth.pipeline.DepthConfig`
DEPTH_OPTIONS = tuple(f.name for f in dataclasses.fields(DepthConfig))
#: the files :meth:`Simulation.save` (and ``prismstereo simulate``) writes
SIMULATION_FILES = ("capture.png", "depth_gt.pfm", "faces.png", "rig.toml", "scene.toml")

PathLike = str | os.PathLike[str]


def _is_path(value: Any) -> bool:
    return isinstance(value, (str, os.PathLike))


def _rig(rig: Rig | PathLike) -> Rig:
    if isinstance(rig, Rig):
        return rig
    if not _is_path(rig):
        raise ConfigError(f"rig: expected a Rig or the path of a rig TOML (docs/rig.md), got {type(rig).__name__}")
    return load_rig(rig)


# --------------------------------------------------------------------------- depth
def depth_config(*, preset: str | None = None, config: DepthConfig | None = None, **options: Any) -> DepthConfig:
    """The configuration :func:`depth` runs: ``config`` (default :class:`DepthConfig()`), the ``preset``'s
    profile (its matcher and depth settings, :data:`prismstereo.depth.presets.PROFILES`), then ``options``
    (fields of :class:`DepthConfig`, :data:`DEPTH_OPTIONS`): an option given explicitly wins over the preset.

    Raises
    ------
    ConfigError
        An unknown option or preset, a preset together with ``method``, or a value out of range
        (:class:`DepthConfig` checks itself).
    """
    unknown = sorted(set(options) - set(DEPTH_OPTIONS))
    if unknown:
        raise ConfigError(f"{unknown[0]}: expected options of depth() among {', '.join(DEPTH_OPTIONS)}, got "
                          f"{', '.join(unknown)} (matcher parameters go in matcher_params={{...}})")
    changes = dict(options)
    base = config if config is not None else DepthConfig()
    if preset is not None:
        base = apply_preset(base, preset, given=changes)
    if "method" in changes and "matcher_params" not in changes and str(changes["method"]).lower() != base.method:
        changes["matcher_params"] = {}  # another matcher: the base's parameters are not its own
    return replace(base, **changes)


@dataclass(frozen=True, eq=False)
class DepthResult:
    """What :func:`depth` found: the maps, the point cloud, and :meth:`save`.

    Attributes
    ----------
    run : prismstereo.depth.pipeline.DepthRun
        The pipeline's full record: every intermediate map (rectified views, raw and filled disparity),
        the rectification, timings, counts and warnings.
    inputs : dict
        The paths the inputs came from (``rig``, ``image``, ``gt``; None for in-memory values), for ``run.json``.
    preset : str or None
    refined_rig : Rig or None
        The rig refined from the capture itself (``self_calibrate=True``); ``run.rig`` is the same rig.
    calibration : SceneCalibration or None
        That refinement's record.
    unobserved : dict or None
        With ``calibration``: the depth error that the parameters the scene did not observe can cause
        (:func:`~prismstereo.calibration.scene_uncertainty.unobserved_depth_error`), in ``run.json``.
    """

    run: DepthRun
    inputs: dict[str, str | None] = field(default_factory=dict)
    preset: str | None = None
    refined_rig: Rig | None = None
    calibration: SceneCalibration | None = None
    unobserved: dict[str, Any] | None = None

    @property
    def depth(self) -> np.ndarray:
        """(h, w) float32 world Z, mm, NaN where there is no point (grid: see :attr:`grid`)."""
        return self.run.depth

    @property
    def disparity(self) -> np.ndarray | None:
        """(h, w) float32 disparity on the rectified left view, px, NaN invalid (None for ``views="all"``)."""
        return self.run.disparity

    @property
    def confidence(self) -> np.ndarray | None:
        """(h, w) float32 confidence in [0, 1] of each point, NaN where there is none (None for ``views="all"``)."""
        return self.run.point_confidence() if self.run.confidence is not None else None

    @property
    def grid(self) -> str:
        """The maps' pixel grid: ``"rectified left"`` (a pair of faces) or ``"capture"`` (``views="all"``)."""
        return "rectified left" if self.run.pair is not None else "capture"

    @property
    def config(self) -> DepthConfig:
        """The resolved configuration (every matcher parameter with its default); ``run.json`` records it."""
        return self.run.config

    @property
    def rig(self) -> Rig:
        return self.run.rig

    @property
    def warnings(self) -> tuple[str, ...]:
        """One-line warnings: the result may be unreliable (also logged and written to ``run.json``)."""
        return self.run.warnings

    @property
    def accuracy(self) -> dict[str, Any] | None:
        """Accuracy against ``ground_truth`` (:func:`~prismstereo.evaluation.depth_metrics.evaluate_depth`)."""
        return self.run.accuracy

    def points(self) -> tuple[np.ndarray, np.ndarray]:
        """The point cloud: (N, 3) float64 world points, mm (real camera frame), and their (N, 3) uint8 RGB."""
        return self.run.point_cloud()

    def summary(self) -> dict[str, Any]:
        """What ``run.json`` holds: the resolved configuration, the rig, versions, timings, counts, warnings."""
        return {**self.run.summary(), **self._extra()}

    def _extra(self) -> dict[str, Any]:
        extra: dict[str, Any] = {"inputs": dict(self.inputs), "preset": self.preset}
        if self.preset is not None:
            extra["preset_profile"] = preset_record(self.preset, self.run.config)
        if self.calibration is not None:
            report = {k: v for k, v in self.calibration.report().items() if k != "rig"}
            if self.unobserved is not None:
                report["depth_error_unobserved"] = self.unobserved
                report["warnings"] = uncertainty_warnings(self.unobserved)
            extra["self_calibration"] = report
        return extra

    def save(self, folder: PathLike, *, report: bool = True) -> dict[str, Path]:
        """Write what ``prismstereo depth`` writes into ``folder`` (created if needed), all files or none.

        A pair of faces: ``disparity.pfm``, ``disparity.png``, ``depth.pfm``, ``confidence.pfm``,
        ``points.ply``, ``report.png`` (``report=False``: not rendered) and ``run.json`` (the resolved
        configuration among the rest); ``views="all"``: ``depth.pfm``, ``depth.png``, ``views.png``,
        ``points.ply`` and ``run.json``; with ``self_calibrate``, ``rig_refined.toml`` too
        (docs/formats.md).

        Returns
        -------
        dict file name -> path written.

        Raises
        ------
        OutputError
            ``folder`` cannot be written; nothing is left behind.
        """
        refined = self.refined_rig
        save_rig: Callable[[Path], None] | None = None
        if refined is not None:
            def save_rig(stage: Path) -> None:
                refined.save(stage / "rig_refined.toml")
        written = write_depth_outputs(self.run, folder, report=report, extra=self._extra(), also=save_rig)
        if refined is not None:
            written["rig_refined.toml"] = Path(folder) / "rig_refined.toml"
        return written


def _capture(rig: Rig, image: np.ndarray | PathLike) -> np.ndarray:
    if isinstance(image, (str, os.PathLike)):
        return read_image(image, expected_size=(rig.camera.width, rig.camera.height),
                          what="capture (the rig's camera size)")
    if not isinstance(image, np.ndarray):
        raise ImageError(f"image: expected an array or the path of an image file, got {type(image).__name__}")
    return image


def _ground_truth(rig: Rig, ground_truth: np.ndarray | PathLike) -> np.ndarray:
    if isinstance(ground_truth, (str, os.PathLike)):
        return read_depth_gt(ground_truth, rig)
    gt = np.asarray(ground_truth, dtype=np.float64)
    if gt.shape != (rig.camera.height, rig.camera.width):
        raise ConfigError(f"ground_truth: expected a {rig.camera.width}×{rig.camera.height} depth map, got shape "
                          f"{gt.shape}")
    return gt


def depth(rig: Rig | PathLike, image: np.ndarray | PathLike, *, preset: str | None = None,
          config: DepthConfig | None = None, ground_truth: np.ndarray | PathLike | None = None,
          self_calibrate: bool = False, progress: bool | None = None, **options: Any) -> DepthResult:
    """Depth map and point cloud of one prism capture (``prismstereo depth``).

    Parameters
    ----------
    rig : Rig or path
        The rig, or its TOML file (docs/rig.md).
    image : (H, W) or (H, W, 3) array, or path
        The capture, RGB, the rig camera's size (docs/conventions.md for the dtypes accepted).
    preset : {"fast", "balanced", "accurate"}, optional
        A profile by what a run may cost: its matcher and the depth settings it implies
        (:data:`prismstereo.depth.presets.PROFILES`; ``fast`` a video frame's refinement); not with
        ``method``; options given explicitly win over its settings.
    config : DepthConfig, optional
        A base configuration (e.g. ``DepthConfig.from_dict(run_json["config"])``); ``options`` override it.
    ground_truth : (H, W) array or path, optional
        World Z per real pixel, mm (``simulate``'s ``depth_gt.pfm``): :attr:`DepthResult.accuracy` is measured.
    self_calibrate : bool
        First refine the prism's rotation and tilt from feature matches in this capture
        (:func:`~prismstereo.calibration.from_scene.calibrate_from_scene`); a pair of faces only.
    progress : bool, optional
        A progress bar per step; default: only on a terminal.
    **options
        Fields of :class:`~prismstereo.depth.pipeline.DepthConfig` (:data:`DEPTH_OPTIONS`): ``method``,
        ``matcher_params``, ``depth_range`` (mm), ``roi``, ``views``, ``triangulation``, ``min_confidence``, ...

    Returns
    -------
    DepthResult
        ``.depth``, ``.disparity``, ``.confidence``, ``.points()``, ``.save(folder)``.

    Raises
    ------
    ConfigError
        A bad option, found before the image is read; ImageError, GeometryError, MatchingError as
        :func:`~prismstereo.depth.pipeline.run_depth`.
    """
    rig_ = _rig(rig)
    cfg = validate_config(rig_, depth_config(preset=preset, config=config, **options))
    if self_calibrate and cfg.views == "all":
        raise ConfigError("self_calibrate: expected a pair of faces (views=(i, j)), got views='all'")
    if cfg.views != "all":  # planned before the capture is read; refused here if even a tiled run cannot fit
        check_depth_memory(rig_, cfg)
    img = validate_image(rig_, _capture(rig_, image))
    depth_gt = None if ground_truth is None else _ground_truth(rig_, ground_truth)
    scene_cal = None
    unobserved = None
    calib_warnings: tuple[str, ...] = ()
    if self_calibrate:
        scene_cal = calibrate_from_scene(rig_, [img])
        rig_ = scene_cal.rig
        # what the parameters the scene did not observe can do to the depth, at the scene's depths
        unobserved = unobserved_depth_error(scene_cal)
        calib_warnings = tuple(uncertainty_warnings(unobserved))
        for line in calib_warnings:
            log.warning("%s", line)
    res = run_depth(rig_, img, config=cfg, progress=progress)
    if calib_warnings:
        # the depth's own warnings (run.json's "warnings", report.png) must say it too: its scale rests on them
        res = dataclasses.replace(res, warnings=calib_warnings + res.warnings)
    if depth_gt is not None:
        res = dataclasses.replace(res, accuracy=evaluate_depth(res, depth_gt=depth_gt))
    inputs = {"rig": None if isinstance(rig, Rig) else str(rig), "image": str(image) if _is_path(image) else None,
              "gt": str(ground_truth) if ground_truth is not None and _is_path(ground_truth) else None}
    return DepthResult(run=res, inputs=inputs, preset=None if preset is None else str(preset).lower(),
                       refined_rig=None if scene_cal is None else scene_cal.rig, calibration=scene_cal,
                       unobserved=unobserved)


# --------------------------------------------------------------------------- simulate
@dataclass(frozen=True, eq=False)
class Simulation:
    """A rendered prism capture with its exact ground truth (:func:`simulate`).

    Attributes
    ----------
    rig : Rig
    scene : Scene
    capture : Capture
        The render: ``image`` (H, W, 3) uint8, ``depth`` (H, W) world Z mm (NaN none), ``faces`` (H, W) uint8.
    """

    rig: Rig
    scene: Scene
    capture: Capture

    @property
    def image(self) -> np.ndarray:
        """(H, W, 3) uint8 RGB: the capture, for :func:`depth`."""
        return self.capture.image

    @property
    def depth_gt(self) -> np.ndarray:
        """(H, W) float world Z per real pixel, mm, NaN where no object is seen: :func:`depth`'s ``ground_truth``."""
        return self.capture.depth

    @property
    def faces(self) -> np.ndarray:
        """(H, W) uint8 face index seen at each pixel, 255 = none."""
        return self.capture.faces

    def save(self, folder: PathLike) -> list[Path]:
        """Write what ``prismstereo simulate`` writes (:data:`SIMULATION_FILES`) into ``folder``, all or none."""
        with output_dir(folder) as staging:
            write_capture(staging, self.rig, self.scene, self.capture)
        return [Path(folder) / f for f in SIMULATION_FILES]

    def summary(self) -> str:
        """One human line: size, faces, time, coverage."""
        cap = self.capture
        h, w = cap.depth.shape
        faces = ", ".join(f"{self.rig.view_name(k)} {100 * v:.1f}%" for k, v in sorted(cap.face_coverage().items()))
        return (f"rendered {w}x{h} ({cap.supersample}x{cap.supersample} samples) through a "
                f"{self.rig.prism.faces}-face prism in {cap.seconds:.2f} s: depth coverage "
                f"{100 * cap.coverage:.1f}%, faces [{faces}]")


def write_capture(out_dir: PathLike, rig: Rig, scene: Scene, capture: Capture) -> None:
    """Write the five files of ``prismstereo simulate`` (docs/cli.md) into an existing folder, each atomically."""
    d = Path(out_dir)
    write_image(d / "capture.png", capture.image)
    write_pfm(d / "depth_gt.pfm", capture.depth)
    write_image(d / "faces.png", capture.faces)
    rig.save(d / "rig.toml")
    atomic_write_text(d / "scene.toml", scene_to_toml(rig, scene))


def check_render_memory(rig: Rig, scene: Scene) -> None:
    """Refuse (ConfigError) a render whose buffers cannot fit in the memory available now."""
    w, h, ss = rig.camera.width, rig.camera.height, scene.supersample
    # per supersample: ray origin + direction (float64 ×6), hit depth, face, colour (float64 ×3): ~100 bytes
    check_fits_in_memory(w * h * ss * ss * 100, what=f"a {w}×{h} render with {ss}×{ss} samples per pixel",
                         hint="lower [camera] width/height (docs/rig.md) or supersample", error=ConfigError)


def simulate(scene: Scene | PathLike | None = None, *, rig: Rig | PathLike | None = None,
             supersample: int | None = None) -> Simulation:
    """Render a prism capture with exact ground truth (``prismstereo simulate``).

    Parameters
    ----------
    scene : path, Scene or None
        A scene TOML (its ``[camera]`` and ``[prism]`` are the rig; docs/cli.md), a
        :class:`~prismstereo.simulate.scene.Scene` (then ``rig`` is required), or None: the built-in bi-prism
        "robot" scene on the thesis rig at 512×384 px (``examples/biprism_demo.toml``).
    rig : Rig or path, optional
        The rig a :class:`Scene` is seen through (with a scene TOML: replaces the file's).
    supersample : int, optional
        Samples per pixel side, 1..16 (overrides the scene's).

    Returns
    -------
    Simulation
        ``.image``, ``.depth_gt``, ``.faces``, ``.rig``, ``.save(folder)``.

    Raises
    ------
    ConfigError
        A bad scene, ``supersample`` out of range, or a render that cannot fit in memory (before rendering).
    """
    if supersample is not None and (isinstance(supersample, bool) or not isinstance(supersample, int | np.integer)
                                    or not 1 <= supersample <= 16):
        raise ConfigError(f"supersample: expected an integer in 1..16, got {supersample!r}")
    if scene is None:
        rig_, scene_ = robot_scene(width=512)
    elif isinstance(scene, Scene):
        if rig is None:
            raise ConfigError("rig: expected the rig a Scene is seen through, got none")
        rig_, scene_ = _rig(rig), scene
    elif _is_path(scene):
        rig_, scene_ = load_scene(scene)
    else:
        raise ConfigError(f"scene: expected a scene TOML path, a Scene or None, got {type(scene).__name__}")
    if rig is not None and not isinstance(scene, Scene):
        rig_ = _rig(rig)
    if supersample is not None:
        scene_ = replace(scene_, supersample=int(supersample))
    check_render_memory(rig_, scene_)
    return Simulation(rig=rig_, scene=scene_, capture=render_capture(rig_, scene_))


# --------------------------------------------------------------------------- calibrate the prism
@dataclass(frozen=True, eq=False)
class Calibration:
    """A prism calibration (:func:`calibrate_prism`): the fitted rig and :meth:`save`.

    Attributes
    ----------
    rig : Rig
        The input rig with the fitted prism (and camera) parameters.
    result : PrismCalibration or SceneCalibration
        The fit's record (estimates, residuals, per-view RMS); ``result.summary()`` is the printed table.
    inputs : dict
        The rig and capture paths (None for in-memory values), for the report.
    """

    rig: Rig
    result: PrismCalibration | SceneCalibration
    inputs: dict[str, Any] = field(default_factory=dict)

    def summary(self) -> str:
        return self.result.summary()

    def files(self, path: PathLike) -> list[Path]:
        """What :meth:`save` writes for ``path``: the rig TOML, ``<stem>.report.json`` and, after a
        checkerboard fit, ``<stem>.residuals.png``."""
        out = Path(path)
        stem = out.with_suffix("") if out.suffix == ".toml" else out
        extra = [Path(f"{stem}.report.json")]
        if isinstance(self.result, PrismCalibration):
            extra.append(Path(f"{stem}.residuals.png"))
        return [out, *extra]

    def save(self, path: PathLike) -> list[Path]:
        """Write what ``prismstereo calibrate-prism`` writes: the fitted rig at ``path`` (last: a rig file on
        disk means the whole calibration was saved), its report and the residual figure beside it."""
        out, report_path, *plot = self.files(path)
        if isinstance(self.result, PrismCalibration):
            png = residual_figure(self.result, self.rig.camera.width, self.rig.camera.height)
            write_json(report_path, self.result.report())
            atomic_write_bytes(plot[0], png)
        else:
            write_json(report_path, {"inputs": dict(self.inputs), **self.result.report()})
        self.rig.save(out)
        return [out, report_path, *plot]


def _images(images: Sequence[np.ndarray | PathLike], what: str) -> tuple[list[np.ndarray], list[str]]:
    if _is_path(images) or isinstance(images, np.ndarray) or not isinstance(images, Sequence):
        raise ImageError(f"{what}: expected a sequence of images or paths, got {type(images).__name__}")
    if not images:
        raise ImageError(f"{what}: expected at least one image, got none")
    arrays = [read_image(p) if isinstance(p, (str, os.PathLike)) else np.asarray(p) for p in images]
    names = [Path(p).name if isinstance(p, (str, os.PathLike)) else f"capture{i}" for i, p in enumerate(images)]
    return arrays, names


def calibrate_prism(rig: Rig | PathLike, captures: Sequence[np.ndarray | PathLike], *,
                    board: Board | str | None = None, square: float | None = None,
                    free: Sequence[str] | str | None = None, from_scene: bool = False,
                    **fit_options: Any) -> Calibration:
    """Fit the prism's pose to captures taken through it (``prismstereo calibrate-prism``).

    Parameters
    ----------
    rig : Rig or path
        The calibrated camera and the nominal prism (the starting point).
    captures : sequence of arrays or paths
        Captures of a checkerboard seen whole through every face, or (``from_scene``) of any textured scene.
    board : Board or "COLSxROWS", optional
        The checkerboard's inner corners (with ``square``, mm, when a string); not with ``from_scene``.
    square : float, optional
        Square side, mm.
    free : parameters to fit (comma string or sequence); default rotation, tilt, decenter, focal (boards)
        or rotation, tilt (``from_scene``).
    from_scene : bool
        Self-calibration from feature matches between the sub-images (no checkerboard).
    **fit_options
        Further keywords of :func:`prismstereo.calibration.calibrate_prism` or
        :func:`~prismstereo.calibration.from_scene.calibrate_from_scene`.

    Returns
    -------
    Calibration
        ``.rig``, ``.summary()``, ``.save(path)``.

    Raises
    ------
    ConfigError
        Bad options, found before any capture is read; ImageError, GeometryError from the fit.
    """
    if from_scene:
        if board is not None or square is not None:
            raise ConfigError("board: expected no board or square with from_scene=True (the scene needs no "
                              "checkerboard), got them")
        scene_free = parse_scene_free(free)
        rig_ = _rig(rig)
        images, _ = _images(captures, "captures")
        result: PrismCalibration | SceneCalibration = calibrate_from_scene(rig_, images, free=scene_free,
                                                                           **fit_options)
    else:
        if board is None:
            raise ConfigError("board: expected a checkerboard (board='COLSxROWS', square=MM) or from_scene=True, "
                              "got neither")
        if isinstance(board, Board):
            board_ = board
        elif square is None:
            raise ConfigError(f"square: expected the square side in mm with board={board!r}, got none")
        else:
            board_ = parse_board(board, square)
        board_free = parse_free(free)
        rig_ = _rig(rig)
        images, names = _images(captures, "captures")
        result = fit_prism_to_boards(rig_, images, board_, names=names, free=board_free, **fit_options)
    inputs = {"rig": None if isinstance(rig, Rig) else str(rig),
              "captures": [str(p) if _is_path(p) else None for p in captures]}
    return Calibration(rig=result.rig, result=result, inputs=inputs)

