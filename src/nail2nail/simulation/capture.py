"""Simulated captures: render a scene for every camera and write a capture directory.

:func:`simulate` renders in memory (frames and ground-truth geometry per camera);
:func:`simulate_capture` also writes the capture directory of ``docs/capture-format.md``
(manifest, PNG frames, ``truth/``).
"""

from __future__ import annotations

import os
import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image

from nail2nail._progress import progress_bar
from nail2nail._validation import one_line
from nail2nail.calibration.distortion import (
    THESIS_CENTER,
    THESIS_RHO,
    ProjectorDistortion,
)
from nail2nail.io._atomic import atomic_directory, check_output_directory, write_npz
from nail2nail.io._json import read_json, write_json
from nail2nail.io.capture import write_frame, write_manifest
from nail2nail.io.prints import write_print_image
from nail2nail.scan.patterns import PatternSet, default_pattern_set, make_patterns
from nail2nail.simulation.motion import Motion, Moved
from nail2nail.simulation.render import (
    CameraGeometry,
    _LightPlan,
    camera_geometry,
    expose,
    frame_flicker,
    projector_radiance,
    render_frames,
)
from nail2nail.simulation.rig import (
    Rig,
    check_camera_sizes,
    default_rig,
    ideal_calibration,
    scale_camera,
)
from nail2nail.simulation.scenes import Finger, Scene, make_scene

__all__ = [
    "SimulatedCapture",
    "load_pattern_dir",
    "read_pattern_dir",
    "simulate",
    "simulate_capture",
    "write_capture",
]


@dataclass
class SimulatedCapture:
    """Result of :func:`simulate`.

    Attributes
    ----------
    frames : dict of str to (n_frames, H, W) uint8/uint16
        Rendered frames per camera name.
    geometry : dict of str to CameraGeometry
        Ground truth per camera name.
    rig : Rig
    scene : Scene
    pattern_set : PatternSet or None
    motion : Motion or None
        The finger's trajectory (:mod:`nail2nail.simulation.motion`); `geometry` is then the
        truth at its reference frame.
    """

    frames: dict
    geometry: dict
    rig: Rig
    scene: Scene
    pattern_set: PatternSet | None = None
    extra: dict = field(default_factory=dict)
    motion: Motion | None = None


def load_pattern_dir(directory: str | os.PathLike) -> tuple[np.ndarray, list[str]]:
    """Panel images from the PNG files of a directory, in sorted name order; for a directory
    written by ``nail2nail patterns`` the frames its ``patterns.json`` lists, in its order
    (not ``grid.png``): :func:`read_pattern_dir`.

    Returns
    -------
    patterns : (n_frames, Hp, Wp) uint8
    names : list of str
    """
    patterns, names, _ = read_pattern_dir(directory)
    return patterns, names


def read_pattern_dir(directory: str | os.PathLike):
    """Panel images of a directory and, from its ``patterns.json`` if any, the pattern set.

    A directory written by ``nail2nail patterns`` (``patterns.json`` beside the PNGs): the
    frames it lists, in frame order, and its pattern set (any scheme), which a capture
    rendered from them should record (``simulate_capture(pattern_set=…)``) so that ``scan``
    decodes it. Any other directory: every PNG in sorted name order, and ``None``.

    Returns
    -------
    patterns : (n_frames, Hp, Wp) uint8
    names : list of str
    pattern_set : PatternSet or None

    Raises
    ------
    ValueError
        Not a directory, no PNG, an image that cannot be read (truncated, corrupt: naming
        the file), images of different sizes, a ``patterns.json`` that is not valid or lists
        missing files.
    """

    directory = Path(directory)
    if not directory.is_dir():
        raise ValueError(f"{directory}: not a directory of pattern PNGs")
    pattern_set = None
    spec = directory / "patterns.json"
    if spec.is_file():
        manifest = read_json(spec)
        try:
            pattern_set = PatternSet.from_dict(manifest["pattern_set"])
            files = [directory / str(frame["file"]) for frame in manifest["frames"]]
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{spec}: not a pattern manifest of nail2nail patterns "
                             f"({exc})") from exc
        missing = [f.name for f in files if not f.is_file() or f.parent != directory]
        if missing or len(files) != pattern_set.n_frames:
            raise ValueError(f"{spec}: lists {len(files)} frames for a pattern set of "
                             f"{pattern_set.n_frames}, missing {missing[:3]}")
    else:
        files = sorted(p for p in directory.iterdir() if p.suffix.lower() == ".png")
    if not files:
        raise ValueError(f"{directory}: no .png pattern files")
    images = []
    for f in files:
        try:
            with warnings.catch_warnings():  # a decompression bomb: an error, not a warning
                warnings.simplefilter("error", Image.DecompressionBombWarning)
                with Image.open(f) as im:
                    images.append(np.asarray(im.convert("L")))
        except Exception as exc:  # truncated, corrupt, not an image: the file and why
            raise ValueError(f"{f}: cannot read pattern image ({one_line(exc)})") from exc
    shapes = {im.shape for im in images}
    if len(shapes) != 1:
        raise ValueError(f"{directory}: pattern images differ in size ({sorted(shapes)})")
    return np.stack(images), [f.name for f in files], pattern_set


def _default_patterns():

    pattern_set = default_pattern_set()
    return make_patterns(pattern_set), pattern_set


def simulate(
    scene: Scene | str = "finger",
    *,
    rig: Rig | None = None,
    patterns=None,
    pattern_set=None,
    seed: int = 0,
    cameras: list[int] | None = None,
    progress: bool = False,
    geometry: dict | None = None,
    motion: Motion | None = None,
    motion_cache: dict | None = None,
) -> SimulatedCapture:
    """Render a scene with every camera of a rig, in memory.

    Parameters
    ----------
    scene : Scene or str
        A scene or its name (:func:`~nail2nail.simulation.scenes.make_scene`, with `seed`).
    rig : Rig, optional
        :func:`~nail2nail.simulation.rig.default_rig` by default.
    patterns : (n_frames, Hp, Wp) uint8, optional
        Panel images; by default those of `pattern_set`, and by default the pattern set is
        ``nail2nail.scan.patterns.default_pattern_set()``.
    pattern_set : PatternSet, optional
        Recorded with the capture; rendered when `patterns` is not given.
    seed : int
        Fingerprint and noise seed.
    cameras : list of int, optional
        Camera indices to render (all by default).
    progress : bool
        Show a progress bar on stderr (a terminal only: :mod:`nail2nail._progress`).
    geometry : dict of str to CameraGeometry, optional
        The cameras' geometry from an earlier :func:`simulate` of the same `scene` object and
        `rig` (``SimulatedCapture.geometry``): the rays are not intersected again, only the
        frames of the new `patterns` rendered (the same finger under other patterns, e.g. the
        pre-distorted ones of the look-up-table correction). Geometry does not depend on
        the patterns, nor on the noise `seed`.
    motion : Motion, optional
        Move the scene rigidly along this trajectory (:func:`~nail2nail.simulation.motion.
        tremor`): frame ``k`` is the mean of the scene rendered at each sub-step of its
        exposure (motion blur), every sub-step with its own ray intersection (so shading,
        shadows and the print move with the finger); the geometry returned (the truth) is
        the scene at the trajectory's reference pose. Needs at least as many trajectory
        frames as patterns.
    motion_cache : dict, optional
        Reuse the moved geometries across calls with the same scene, rig and `motion` (for
        instance the same tremor under several pattern sets of one panel size): filled with
        what rendering needs of each ``(camera, frame, step)``.

    Returns
    -------
    SimulatedCapture
    """
    rig = rig or default_rig()
    if isinstance(scene, str):
        scene = make_scene(scene, rig=rig, seed=seed)
    if patterns is None:
        if pattern_set is None:
            patterns, pattern_set = _default_patterns()
        else:

            patterns = make_patterns(pattern_set)
    patterns = np.asarray(patterns)
    if patterns.ndim != 3 or patterns.dtype != np.uint8:
        raise ValueError(f"patterns: expected (n_frames, Hp, Wp) uint8, got {patterns.dtype} "
                         f"{patterns.shape}")
    pw, ph = rig.panel_size
    if patterns.shape[1:] != (ph, pw):
        raise ValueError(f"patterns: panel images are {patterns.shape[2]}x{patterns.shape[1]}, "
                         f"the rig's projector is {pw}x{ph}")
    indices = list(range(len(rig.cameras))) if cameras is None else list(cameras)
    radiance = [projector_radiance(p, rig.photometry) for p in patterns]
    flicker = frame_flicker(rig.photometry, len(patterns), seed)
    if flicker is not None:  # the projector's frames, the same for every camera
        radiance = [r * f for r, f in zip(radiance, flicker, strict=True)]
    known, geometry = geometry, {}
    frames = {}
    missing = [] if known is None else [rig.camera_names[i] for i in indices
                                         if rig.camera_names[i] not in known]
    if missing:
        raise ValueError(f"geometry: no camera {missing[0]!r} (has {sorted(known or {})})")
    if motion is not None and motion.n_frames < len(patterns):
        raise ValueError(f"motion: covers {motion.n_frames} frames, the patterns are "
                         f"{len(patterns)}")
    for i in progress_bar(indices, desc="simulate", unit="camera", enabled=progress):
        name = rig.camera_names[i]
        geom = camera_geometry(rig, scene, i) if known is None else known[name]
        geometry[name] = geom
        if motion is None:
            frames[name] = render_frames(geom, patterns, rig.photometry, seed=seed,
                                         camera_index=i, scale=rig.scale, radiance=radiance)
        else:
            frames[name] = _moving_frames(rig, scene, i, patterns, radiance, motion, seed=seed,
                                          cache={} if motion_cache is None else motion_cache)
    return SimulatedCapture(frames=frames, geometry=geometry, rig=rig, scene=scene,
                            pattern_set=pattern_set, motion=motion)


def _moving_frames(rig: Rig, scene: Scene, camera_index: int, patterns, radiance,
                   motion: Motion, *, seed: int, cache: dict) -> np.ndarray:
    """Frames of one camera with the scene moving along `motion` (see :func:`simulate`)."""
    name = rig.camera_names[camera_index]
    out = None
    for k in range(len(patterns)):
        signal = None
        for j in range(motion.blur_steps):
            key = (name, k, j)
            if key not in cache:  # what rendering needs, not the geometry's truth arrays
                geometry = camera_geometry(rig, Moved(scene, *motion.pose(k, j)), camera_index)
                cache[key] = _LightPlan(geometry, rig.photometry, patterns.shape[1:])
            step = cache[key].signal(radiance[k])
            signal = step if signal is None else signal + step
        assert signal is not None
        frame = expose(signal / np.float32(motion.blur_steps), rig.photometry, seed=seed,
                       camera_index=camera_index, frame=k, scale=rig.scale,
                       margin=cache[key].margin)
        if out is None:
            out = np.empty((len(patterns), *frame.shape), frame.dtype)
        out[k] = frame
    assert out is not None
    return out


def simulate_capture(
    out_dir: str | os.PathLike,
    scene: Scene | str = "finger",
    *,
    rig: Rig | None = None,
    scale: float | None = None,
    projector_distortion: str | None = None,
    patterns=None,
    pattern_set=None,
    pattern_names: list[str] | None = None,
    seed: int = 0,
    write_truth: bool = True,
    progress: bool = False,
    print_image=None,
    print_ppi: float = 500.0,
    motion: Motion | None = None,
) -> dict:
    """Render a scene and write a capture directory (``docs/capture-format.md``).

    Parameters
    ----------
    out_dir : path-like
        Created if needed. Written as a whole (:func:`nail2nail.io._atomic.atomic_directory`):
        an earlier capture there is replaced only when the new one is complete, and a failed
        or interrupted run leaves it untouched; a non-empty directory without
        ``capture.json`` is refused.
    scene : Scene or str
    rig : Rig, optional
        Default: ``default_rig(scale or 1)``.
    scale : float, optional
        Camera resolution scale (applied to the given rig's cameras, or to the default rig).
    projector_distortion : {"thesis", "none"}, optional
        Override the rig's projector distortion.
    patterns, pattern_set
        As :func:`simulate`; `pattern_names` names the pattern files of a directory source.
    seed : int
    write_truth : bool
        Write ``truth/`` (geometry per camera, rig, ideal calibration, rolled print: for a
        synthetic print the friction-ridge skin from nail edge to nail edge and from the tip
        to ``Finger.rolled_length_mm``, ``docs/capture-format.md``).
    progress : bool
        Show progress bars on stderr (rendering per camera, writing the frames; a terminal
        only: :mod:`nail2nail._progress`).
    print_image : (H, W) uint8, optional
        Finger only (`scene` ``"finger"``): a real print in the legacy convention to wrap
        around the finger instead of the synthetic one (``Finger.print_image``); written back
        unchanged as ``truth/rolled_print.png``.
    print_ppi : float
        Resolution of `print_image`, pixels per inch.
    motion : Motion, optional
        A moving scene (:func:`simulate`); the trajectory goes to ``truth/motion.json``.

    Returns
    -------
    dict
        The manifest written to ``capture.json``.
    """
    check_output_directory(out_dir, marker="capture.json")  # refused before rendering
    rig = _configure_rig(rig, scale=scale, projector_distortion=projector_distortion)
    if print_image is not None:
        if scene != "finger":
            raise ValueError(f"print_image: only for the scene 'finger', got {scene!r}")
        scene = make_scene("finger", rig=rig, seed=seed, print_image=print_image,
                           print_ppi=print_ppi)
    sim = simulate(scene, rig=rig, patterns=patterns, pattern_set=pattern_set, seed=seed,
                   progress=progress, motion=motion)
    return write_capture(out_dir, sim, seed=seed, pattern_names=pattern_names,
                         write_truth=write_truth, progress=progress)


def write_capture(out_dir: str | os.PathLike, sim: SimulatedCapture, *, seed: int = 0,
                  pattern_names: list[str] | None = None, write_truth: bool = True,
                  progress: bool = False) -> dict:
    """Write a simulated capture as a capture directory (``docs/capture-format.md``).

    The second half of :func:`simulate_capture`, for a :class:`SimulatedCapture` already in
    memory; `seed` is recorded in the manifest. The directory is written as a whole
    (:func:`nail2nail.io._atomic.atomic_directory`); `progress` shows a bar of the frames
    written on stderr (a terminal only). Returns the manifest.
    """
    check_output_directory(out_dir, marker="capture.json")
    with atomic_directory(out_dir, marker="capture.json") as out:
        return _write_capture(out, sim, sim.rig, seed=seed, pattern_names=pattern_names,
                              write_truth=write_truth, progress=progress)


def _write_capture(out: Path, sim: SimulatedCapture, rig: Rig, *, seed, pattern_names,
                   write_truth, progress=False) -> dict:
    bits = rig.photometry.bit_depth
    cameras = []
    jobs = []
    for name, frames in sim.frames.items():
        files = [f"{name}/{k:03d}.png" for k in range(len(frames))]
        jobs += [(out / rel, frame) for rel, frame in zip(files, frames, strict=True)]
        h, w = frames.shape[1:]
        cameras.append({"name": name, "size": [int(w), int(h)], "frames": files})
    # PNG encoding (zlib) releases the GIL: the frames are written on every core
    with ThreadPoolExecutor(min(os.cpu_count() or 1, 8)) as pool:
        for done in progress_bar(pool.map(lambda job: write_frame(*job), jobs), desc="write",
                                 unit="frame", total=len(jobs), enabled=progress):
            del done
    n_frames = len(next(iter(sim.frames.values())))
    manifest = {
        "created_by": "nail2nail simulate",
        "scene": {**sim.scene.to_dict(), "seed": seed},
        "bit_depth": bits,
        "n_frames": n_frames,
        "pattern_set": None if sim.pattern_set is None else sim.pattern_set.to_dict(),
        "patterns": (
            {"source": "pattern_set"} if pattern_names is None
            else {"source": "directory", "files": list(pattern_names)}
        ),
        "projector": {"size": list(rig.panel_size)},
        "cameras": cameras,
        "rig": rig.to_dict(),
    }
    if write_truth:
        manifest["truth"] = _write_truth(out, sim)
    write_manifest(out, manifest)
    return {"format": "nail2nail-capture", "version": 1, **manifest}


def _configure_rig(rig, *, scale, projector_distortion) -> Rig:
    if rig is None:
        rig = default_rig(scale or 1.0, projector_distortion=projector_distortion or "thesis")
    else:
        if scale is not None and scale != 1:
            rig = Rig.from_dict(rig.to_dict())
            rig.cameras = [scale_camera(c, scale) for c in rig.cameras]
            rig.scale = rig.scale * scale
        if projector_distortion is not None:
            rig = Rig.from_dict(rig.to_dict())
            if projector_distortion == "none":
                rig.projector_distortion = None
            elif projector_distortion == "thesis":

                rig.projector_distortion = ProjectorDistortion(THESIS_CENTER, THESIS_RHO)
            else:
                raise ValueError("projector_distortion: expected 'thesis' or 'none', got "
                                 f"{projector_distortion!r}")
    check_camera_sizes(rig.cameras, rig.camera_names,
                       "rig" if scale is None else f"scale {scale:g}")
    return rig


def _write_truth(out: Path, sim: SimulatedCapture) -> dict:
    truth = out / "truth"
    entries: dict = {"cameras": {}}
    for name, geom in sim.geometry.items():
        arrays = _truth_arrays(geom)
        write_npz(truth / f"{name}.npz", arrays)
        entries["cameras"][name] = f"truth/{name}.npz"
    write_json(truth / "calibration.json", ideal_calibration(sim.rig))
    entries["calibration"] = "truth/calibration.json"
    if sim.motion is not None:
        # the geometry above is the scene at the trajectory's reference pose
        write_json(truth / "motion.json", sim.motion.to_dict())
        entries["motion"] = "truth/motion.json"
    if isinstance(sim.scene, Finger):
        finger = sim.scene
        image, _ = finger.rolled_print()
        fp = finger.fingerprint
        assert fp is not None  # a Finger always has its print
        minutiae = finger.rolled_print_minutiae()
        # legacy convention; a synthetic print cut to the rolled extent (nail edge to nail
        # edge, tip to rolled_length_mm), a print from an image written back unchanged
        write_print_image(truth / "rolled_print.png", image, ppi=fp.ppi)
        write_json(truth / "fingerprint.json", {
            **fp.describe(),
            **finger.rolled_print_geometry(),
            "skin_grid": fp.geometry(),
            "image": "truth/rolled_print.png",
            "n_minutiae": len(minutiae),
            "minutiae": [
                {"u": round(float(m[0]), 4), "v": round(float(m[1]), 4),
                 "col": int(m[2]), "row": int(m[3]),
                 "kind": "ending" if m[4] == 1 else "bifurcation",
                 "orientation_rad": round(float(m[5]), 4)}
                for m in minutiae
            ],
        })
        entries["rolled_print"] = "truth/rolled_print.png"
        entries["fingerprint"] = "truth/fingerprint.json"
    return entries


def _truth_arrays(geom: CameraGeometry) -> dict:
    arrays = geom.truth_arrays()
    for key in ("albedo", "irradiance", "normal"):
        arrays[key] = arrays[key].astype(np.float32)
    for key in list(arrays):
        if key.startswith("param_"):
            arrays[key] = arrays[key].astype(np.float32)
    return arrays
