"""SourceAFIS matcher harness for the rolled-equivalent print checks (issue 9).

A real minutiae matcher scores 2D prints: SourceAFIS for Java (Apache-2.0, version pinned in
``bench/matcher/pom.xml``) runs as one JVM per call through a small runnable jar built with
Maven (``bench/matcher``, built once and cached in ``bench/matcher/target``). Its scores are
open-ended (not probabilities); SourceAFIS puts the threshold for a 0.01 % false match rate at
40. Images are passed as files (PNG, 8-bit grayscale, ridges dark on white).

Grey images are read as their samples say (grey level = sample value), as SourceAFIS takes raw
pixels and as it reads an RGB or palette file. SourceAFIS's own file decoder goes through Java
``ImageIO`` and ``BufferedImage.getRGB``, which takes the samples of an 8-bit grey PNG for linear
light and converts them to sRGB: every grey level but 0 and 255 reads brighter (128 as 188).
The real prints of ``../shared/data/prints`` are RGBA files, read unchanged, so a print stored
as grey would be compared with them through a different tone curve: ``probe.png`` saved as
8-bit grey scores 203.4 against ``matching.png`` that way instead of its 235.6.
``imageio_grey=True`` (``--imageio-grey``) scores grey files through ImageIO, as this harness
did before 2026-12-08 (every SourceAFIS figure of the README up to then).

Library use (from ``bench/`` scripts or tests, after putting ``bench`` on ``sys.path``)::

    import sourceafis
    if sourceafis.available():
        scores = sourceafis.score_matrix(probe_paths, candidate_paths, dpi=500)

Usage as a script::

    .venv/bin/python bench/sourceafis.py PROBE CANDIDATE [CANDIDATE ...] [--dpi 500]
        [--imageio-grey]
    .venv/bin/python bench/sourceafis.py            # self-check on synthetic prints

The self-check scores a few synthetic fingers against mildly re-rendered copies of themselves
(Gaussian blur σ = 1 px and 2 % scale change: :func:`rerender`) and against each other, and
prints the scores and the time taken. It prints a line and returns when Java or Maven are
missing, so that ``make bench`` still runs.
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import scipy.ndimage as ndi

#: The real prints shared with the project (``../shared/data/prints``: a genuine pair
#: ``probe.png``/``matching.png``, another finger ``nonmatching.png``; Apache-2.0)
PRINTS = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "prints"

__all__ = [
    "JAR_PATH",
    "MATCHER_DIR",
    "available",
    "build",
    "rerender",
    "save_png",
    "score_matrix",
    "score_pairs",
]

MATCHER_DIR = Path(__file__).resolve().parent / "matcher"
"""The Maven project of the matcher harness."""

JAR_PATH = MATCHER_DIR / "target" / "nail2nail-matcher.jar"
"""The runnable jar that :func:`build` produces."""

_BUILD_TIMEOUT_S = 900


def available() -> bool:
    """Whether the matcher can be built and run here.

    Returns
    -------
    bool
        True when ``java`` and ``mvn`` are both on ``PATH``.

    Examples
    --------
    >>> isinstance(available(), bool)
    True
    """
    return shutil.which("java") is not None and shutil.which("mvn") is not None


def _sources() -> list[Path]:
    return [MATCHER_DIR / "pom.xml", *sorted((MATCHER_DIR / "src").rglob("*"))]


def _jar_is_fresh() -> bool:
    if not JAR_PATH.is_file():
        return False
    newest = max(p.stat().st_mtime for p in _sources() if p.is_file())
    return JAR_PATH.stat().st_mtime >= newest


def build(*, quiet: bool = True) -> Path:
    """Build the matcher jar with Maven unless it is newer than its sources.

    Runs ``mvn -q -B package`` in ``bench/matcher``. The first build downloads SourceAFIS
    and the Maven plugins from Maven Central (about a minute); later calls return at once.

    Parameters
    ----------
    quiet : bool
        Keep Maven's output to errors (``-q``); Maven's output is shown on failure anyway.

    Returns
    -------
    Path
        The runnable jar, ``bench/matcher/target/nail2nail-matcher.jar``.

    Raises
    ------
    RuntimeError
        If ``java`` or ``mvn`` is missing, or the build fails (with Maven's last output).
    """
    if _jar_is_fresh():
        return JAR_PATH
    if not available():
        raise RuntimeError("build: the SourceAFIS matcher needs `java` (17+) and `mvn` on PATH")
    cmd = ["mvn", "-B", "-Dstyle.color=never", "package"]
    if quiet:
        cmd.insert(1, "-q")
    proc = subprocess.run(cmd, cwd=MATCHER_DIR, capture_output=True, text=True,
                          timeout=_BUILD_TIMEOUT_S, check=False)
    if proc.returncode != 0 or not JAR_PATH.is_file():
        tail = (proc.stdout + proc.stderr).strip().splitlines()[-30:]
        raise RuntimeError(
            f"build: `{' '.join(cmd)}` in {MATCHER_DIR} failed (exit {proc.returncode}):\n"
            + "\n".join(tail)
        )
    if not quiet and proc.stdout:
        print(proc.stdout, end="")
    return JAR_PATH


def _check_path(value, name: str) -> str:
    if not isinstance(value, str | os.PathLike):
        raise TypeError(f"{name}: expected a path, got {type(value).__name__}")
    path = Path(value).resolve()
    text = str(path)
    if "\t" in text or "\n" in text or "\r" in text:
        raise ValueError(f"{name}: paths with tabs or line breaks are not supported: {text!r}")
    if not path.is_file():
        raise FileNotFoundError(f"{name}: no such image file: {text}")
    return text


def _check_dpi(dpi) -> float:
    if isinstance(dpi, bool) or not isinstance(dpi, int | float | np.integer | np.floating):
        raise TypeError(f"dpi: expected a number, got {type(dpi).__name__}")
    if not (math.isfinite(dpi) and 20 <= dpi <= 20000):
        raise ValueError(f"dpi: expected 20..20000, got {dpi}")
    return float(dpi)


def score_pairs(pairs: Sequence[tuple[str | os.PathLike, str | os.PathLike]], *,
                dpi: float = 500, imageio_grey: bool = False) -> np.ndarray:
    """Score (probe, candidate) image pairs with SourceAFIS, all in one JVM run.

    Templates are extracted once per distinct path, so repeated images cost one extraction.
    An 8-bit grey image is read as its samples say (grey level = sample), as an RGB or palette
    image is: SourceAFIS's own file decoder (Java ``ImageIO``, ``getRGB``) takes grey PNG
    samples for linear light and brightens them to sRGB (128 reads as 188), which costs a print
    part of its score against one stored in colour (``probe.png`` saved as 8-bit grey scores 203.4
    against ``matching.png`` instead of 235.6).

    Parameters
    ----------
    pairs : sequence of (path, path)
        Probe and candidate image files (PNG, 8-bit grayscale, ridges dark).
    dpi : float
        Resolution of all the images, pixels per inch (SourceAFIS rescales to 500 ppi).
    imageio_grey : bool
        Read grey images through SourceAFIS's decoder instead, brightened (the figures of
        this harness before 2026-12-08 were measured that way).

    Returns
    -------
    scores : (N,) float64
        SourceAFIS similarity scores, in the order of `pairs`; 40 is SourceAFIS's threshold for
        a 0.01 % false match rate. An empty `pairs` gives an empty array without running Java.

    Raises
    ------
    TypeError
        If a pair is not two paths, or `dpi` is not a number.
    ValueError
        If `dpi` is outside 20..20000 or a path holds a tab or line break.
    FileNotFoundError
        If an image file is missing.
    RuntimeError
        If Java/Maven are missing, the build fails or the matcher fails on an image.
    """
    dpi = _check_dpi(dpi)
    lines = []
    for i, pair in enumerate(pairs):
        if isinstance(pair, str | os.PathLike) or len(pair) != 2:
            raise TypeError(f"pairs[{i}]: expected a (probe, candidate) pair of paths")
        probe = _check_path(pair[0], f"pairs[{i}][0]")
        candidate = _check_path(pair[1], f"pairs[{i}][1]")
        lines.append(f"{probe}\t{candidate}\n")
    if not lines:
        return np.zeros(0)
    jar = build()
    cmd = ["java", "-jar", str(jar), "--dpi", repr(dpi), *(["--imageio-grey"] if imageio_grey
                                                           else [])]
    proc = subprocess.run(cmd, input="".join(lines), capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"score_pairs: the SourceAFIS matcher failed (exit "
                           f"{proc.returncode}): {proc.stderr.strip()[-2000:]}")
    out = proc.stdout.split()
    if len(out) != len(lines):
        raise RuntimeError(f"score_pairs: expected {len(lines)} scores from the matcher, "
                           f"got {len(out)}")
    return np.array([float(s) for s in out])


def score_matrix(probes: Sequence[str | os.PathLike], candidates: Sequence[str | os.PathLike],
                 *, dpi: float = 500, imageio_grey: bool = False) -> np.ndarray:
    """Score every probe against every candidate (one JVM run).

    Parameters
    ----------
    probes, candidates : sequence of path
        Image files (PNG, 8-bit grayscale, ridges dark).
    dpi : float
        Resolution of all the images, pixels per inch.
    imageio_grey : bool
        As :func:`score_pairs`.

    Returns
    -------
    scores : (P, C) float64
        ``scores[i, j]`` is the SourceAFIS score of ``probes[i]`` against ``candidates[j]``.

    Raises
    ------
    TypeError, ValueError, FileNotFoundError, RuntimeError
        As :func:`score_pairs`.
    """
    if isinstance(probes, str | os.PathLike) or isinstance(candidates, str | os.PathLike):
        raise TypeError("probes, candidates: expected sequences of paths, got a single path")
    probes, candidates = list(probes), list(candidates)
    pairs = [(p, c) for p in probes for c in candidates]
    return score_pairs(pairs, dpi=dpi, imageio_grey=imageio_grey).reshape(len(probes),
                                                                          len(candidates))


def _check_image(image) -> np.ndarray:
    if not isinstance(image, np.ndarray):
        raise TypeError(f"image: expected a numpy array, got {type(image).__name__}")
    if image.dtype != np.uint8:
        raise TypeError(f"image: expected dtype uint8, got {image.dtype}")
    if image.ndim != 2 or min(image.shape) < 1:
        raise ValueError(f"image: expected shape (H, W), got {image.shape}")
    return image


def rerender(image: np.ndarray, *, blur_px: float = 1.0, scale: float = 1.02,
             angle_deg: float = 0.0, shift_px: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """A mildly re-rendered copy of a print: Gaussian blur, then a scale change (and a rotation,
    a sub-pixel shift) about the centre.

    The reference for "as good as a re-rendering of the truth" in issue 9: the score of a print
    against its own re-rendered copy bounds what any faithful reproduction can reach.

    Parameters
    ----------
    image : (H, W) uint8
        Print, ridges dark on a white (255) background.
    blur_px : float
        Standard deviation of the Gaussian blur, pixels (0: none).
    scale : float
        Magnification about the image centre (``1.02``: 2 % larger); pixels brought in from
        outside the image are white.
    angle_deg : float
        Rotation about the image centre, degrees: output pixel ``o`` (row, col) samples the
        blurred input at ``c + R(angle)(o − c) / scale + shift``, ``c`` the centre and ``R``
        the rotation of (row, col) vectors by `angle_deg`.
    shift_px : (float, float)
        ``shift`` above, (row, col) px: the picture moves by about ``−shift``.

    Returns
    -------
    (H, W) uint8
        The re-rendered print (cubic-spline resampling, rounded and clipped to 0..255).

    Raises
    ------
    TypeError
        If `image` is not a uint8 array.
    ValueError
        If `image` is not 2D, `blur_px` is negative, `scale` is not positive or `angle_deg`,
        `shift_px` are not finite.

    Examples
    --------
    >>> img = np.full((40, 50), 255, np.uint8); img[:, 20:25] = 0
    >>> out = rerender(img)
    >>> out.shape, out.dtype, int(out[0, 0]), int(out[20, 22]) < 40
    ((40, 50), dtype('uint8'), 255, True)
    """
    image = _check_image(image)
    if not (math.isfinite(blur_px) and blur_px >= 0):
        raise ValueError(f"blur_px: expected a finite value >= 0, got {blur_px}")
    if not (math.isfinite(scale) and scale > 0):
        raise ValueError(f"scale: expected a finite value > 0, got {scale}")
    shift = np.asarray(shift_px, dtype=np.float64)
    if not math.isfinite(angle_deg) or shift.shape != (2,) or not np.isfinite(shift).all():
        raise ValueError(f"angle_deg, shift_px: expected a finite angle and two finite numbers, "
                         f"got {angle_deg}, {shift_px}")
    work = image.astype(np.float64)
    if blur_px > 0:
        work = ndi.gaussian_filter(work, blur_px, mode="nearest")
    centre = (np.array(image.shape, dtype=np.float64) - 1) / 2
    if angle_deg != 0 or shift.any():
        a = np.deg2rad(angle_deg)
        matrix = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]) / scale
        work = ndi.affine_transform(work, matrix, offset=centre - matrix @ centre + shift,
                                    order=3, mode="constant", cval=255.0)
    elif scale != 1:
        # output pixel o samples the input at c + (o − c) / scale
        work = ndi.affine_transform(work, np.full(2, 1 / scale), offset=centre - centre / scale,
                                    order=3, mode="constant", cval=255.0)
    return np.clip(np.rint(work), 0, 255).astype(np.uint8)


def save_png(path: str | os.PathLike, image: np.ndarray, *, dpi: float = 500) -> Path:
    """Write an 8-bit grayscale PNG with its resolution recorded, for :func:`score_pairs`.

    Parameters
    ----------
    path : path
        Output file.
    image : (H, W) uint8
        Print, ridges dark on white.
    dpi : float
        Resolution stored in the PNG ``pHYs`` chunk (SourceAFIS uses the ``dpi`` argument of
        :func:`score_pairs`, not this).

    Returns
    -------
    Path
        `path`.

    Raises
    ------
    TypeError, ValueError
        As :func:`rerender` for a bad `image`, or a bad `dpi`.
    """
    from nail2nail.io.prints import write_print_image

    return write_print_image(path, _check_image(image), ppi=_check_dpi(dpi))


def _synthetic_print(seed: int) -> np.ndarray:
    from nail2nail.simulation.fingerprint import generate_fingerprint

    fp = generate_fingerprint(u_range=(-8, 8), v_range=(-10, 10), seed=seed)
    return np.rint(127.5 - 127.5 * fp.ridges).astype(np.uint8)


def _self_check(n_fingers: int, dpi: float) -> None:
    if not available():
        print("skipped: the SourceAFIS matcher needs `java` and `mvn` on PATH")
        return
    t = time.perf_counter()
    build()
    t_build = time.perf_counter() - t
    with tempfile.TemporaryDirectory(prefix="sourceafis-") as tmp:
        t = time.perf_counter()
        truth, copies = [], []
        for seed in range(n_fingers):
            image = _synthetic_print(seed)
            truth.append(save_png(Path(tmp, f"truth{seed}.png"), image))
            copies.append(save_png(Path(tmp, f"rerendered{seed}.png"), rerender(image)))
        t_gen = time.perf_counter() - t
        t = time.perf_counter()
        scores = score_matrix(copies, truth, dpi=dpi)
        t_match = time.perf_counter() - t
    same = np.diag(scores)
    cross = scores[~np.eye(n_fingers, dtype=bool)]
    print(f"{n_fingers} synthetic fingers (16 x 20 mm at {dpi:g} ppi), SourceAFIS scores of the "
          "re-rendered copy (blur 1 px, scale 1.02) against the truth:")
    print("  same finger:      " + " ".join(f"{s:7.1f}" for s in same))
    print(f"  different finger: max {cross.max():.1f}, mean {cross.mean():.1f} "
          f"over {cross.size} pairs (threshold 40)")
    print(f"build check {t_build:.2f} s, print synthesis {t_gen:.2f} s, "
          f"{scores.size} matches in one JVM run {t_match:.2f} s")


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("probe", nargs="?", help="probe image (none: synthetic self-check)")
    parser.add_argument("candidates", nargs="*", help="candidate images")
    parser.add_argument("--dpi", type=float, default=500.0, help="image resolution (500)")
    parser.add_argument("--fingers", type=int, default=5, help="self-check: number of fingers")
    parser.add_argument("--imageio-grey", action="store_true",
                        help="read grey images through ImageIO, brightened (earlier figures)")
    args = parser.parse_args(argv)
    if args.probe is None:
        _self_check(args.fingers, args.dpi)
        return
    if not args.candidates:
        parser.error("give at least one candidate image after the probe")
    scores = score_matrix([args.probe], args.candidates, dpi=args.dpi,
                          imageio_grey=args.imageio_grey)[0]
    for path, score in zip(args.candidates, scores, strict=True):
        print(f"{score:.3f}\t{path}")


if __name__ == "__main__":
    main(sys.argv[1:])
