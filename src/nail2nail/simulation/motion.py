"""A finger that moves: rigid trajectories (tremor and drift) and scenes posed along them.

A touchless finger is held in the air: it trembles (physiological tremor, 8–12 Hz, tens to
hundreds of µm) and drifts while the projector shows its frames. :class:`Motion` is a rigid
trajectory sampled at every frame (and at sub-steps within each exposure, for motion blur);
:func:`tremor` draws one; :class:`Moved` is any scene carried by a rigid motion.

Conventions
-----------
- A pose ``(R, t)`` maps the scene at the reference time to the scene at time ``τ``:
  ``X(τ) = R(τ) (X₀ − c) + c + t(τ)`` with ``c`` the centre of rotation (world mm, the
  finger's middle by default); the reference frame's pose is the identity, so the truth of a
  moving capture (``truth/``) is the surface at the reference frame's mid-exposure time.
- Frame ``k`` is exposed from ``k / frame_rate`` for `exposure_s`; its sub-steps sit at the
  middle of `blur_steps` equal parts of the exposure, and the frame is their mean.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from nail2nail.simulation.scenes import Scene, SurfaceInfo

__all__ = ["Motion", "Moved", "tremor"]


def _rotation(rotvec) -> np.ndarray:
    """Rotation matrix of a rotation vector (rad)."""
    return Rotation.from_rotvec(np.asarray(rotvec, dtype=float)).as_matrix()


@dataclass(frozen=True)
class Motion:
    """A rigid trajectory over a capture's frames.

    Attributes
    ----------
    times_s : (n_frames, blur_steps) float64
        Time of every sub-step of every frame's exposure, s (0 at the first frame's start).
    rotvec_rad : (n_frames, blur_steps, 3) float64
        Rotation of each sub-step from the reference pose, as a rotation vector, rad.
    translation_mm : (n_frames, blur_steps, 3) float64
        Translation of each sub-step from the reference pose, world mm.
    center_mm : (3,) float64
        Centre of rotation, world mm.
    reference_frame : int
        The frame whose mid-exposure pose is the identity (the truth's time).
    frame_rate_hz, exposure_s : float
    description : dict
        How it was drawn (model, amplitudes, frequencies, seed), JSON-ready.
    """

    times_s: np.ndarray
    rotvec_rad: np.ndarray
    translation_mm: np.ndarray
    center_mm: np.ndarray
    reference_frame: int
    frame_rate_hz: float
    exposure_s: float
    description: dict = field(default_factory=dict)

    @property
    def n_frames(self) -> int:
        """Frames the trajectory covers."""
        return int(self.times_s.shape[0])

    @property
    def blur_steps(self) -> int:
        """Sub-steps per exposure."""
        return int(self.times_s.shape[1])

    def pose(self, frame: int, step: int) -> tuple[np.ndarray, np.ndarray]:
        """``(R, t)`` of one sub-step as ``X = R X₀ + t`` (the centre folded into ``t``)."""
        R = _rotation(self.rotvec_rad[frame, step])
        c = self.center_mm
        return R, c - R @ c + self.translation_mm[frame, step]

    def to_dict(self) -> dict:
        """JSON-ready: the model and the pose at every frame's mid-exposure."""
        mid = self.blur_steps // 2
        return {
            **self.description,
            "frame_rate_hz": self.frame_rate_hz,
            "exposure_s": self.exposure_s,
            "blur_steps": self.blur_steps,
            "reference_frame": self.reference_frame,
            "center_mm": np.round(self.center_mm, 6).tolist(),
            "convention": "X(tau) = R(tau) (X0 - center) + center + t(tau); X0 the surface at "
                          "the reference frame (truth/), R from the rotation vector (rad)",
            "frames": [
                {"time_s": round(float(self.times_s[k].mean()), 6),
                 "rotvec_rad": np.round(self.rotvec_rad[k, mid], 9).tolist(),
                 "translation_mm": np.round(self.translation_mm[k, mid], 6).tolist()}
                for k in range(self.n_frames)
            ],
        }


def tremor(
    n_frames: int,
    *,
    amplitude_mm: float = 0.1,
    rotation_deg: float | None = None,
    frequency_hz: tuple[float, float] = (8.0, 12.0),
    drift_mm_s: float = 0.0,
    frame_rate_hz: float = 120.0,
    exposure_s: float | None = None,
    blur_steps: int = 3,
    center_mm=(0.0, 0.0, 0.0),
    reference_frame: int | None = None,
    seed: int = 0,
) -> Motion:
    """Draw a physiological tremor (and a drift) over a capture's frames.

    Each of the three translations and three rotations is a sum of three sinusoids with
    frequencies drawn uniformly from `frequency_hz` and random phases (a narrow-band tremor);
    the translations are scaled together so that the RMS over time of the 3D displacement is
    `amplitude_mm`, the rotations so that the RMS rotation angle is `rotation_deg`. A drift adds
    a constant velocity of `drift_mm_s` in a random direction.

    Parameters
    ----------
    n_frames : int
        Frames of the capture.
    amplitude_mm : float
        RMS of the tremor's 3D translation over time, mm (0.025–0.2 for a finger held in the
        air; 0 for none).
    rotation_deg : float, optional
        RMS rotation angle, degrees. Default: the angle that moves a point 8 mm from the centre
        (a finger's radius) by a third of `amplitude_mm`.
    frequency_hz : (float, float)
        Band of the tremor's frequencies, Hz.
    drift_mm_s : float
        Speed of a slow drift, mm/s.
    frame_rate_hz : float
        Camera and projector frame rate, frames per second.
    exposure_s : float, optional
        Exposure of each frame, s (at most one frame period). Default: the whole frame period.
    blur_steps : int
        Sub-steps per exposure averaged into a frame (1: no motion blur).
    center_mm : (3,) float
        Centre of rotation, world mm.
    reference_frame : int, optional
        The frame at whose mid-exposure the finger is at its reference pose (the truth).
        Default: the middle frame.
    seed : int

    Returns
    -------
    Motion

    Raises
    ------
    ValueError
        A negative or non-finite amplitude, a bad band, rate, exposure or step count.
    """
    if not (isinstance(n_frames, (int, np.integer)) and n_frames >= 1):
        raise ValueError(f"n_frames: expected a positive integer, got {n_frames!r}")
    for name, value in (("amplitude_mm", amplitude_mm), ("drift_mm_s", drift_mm_s)):
        if not (np.isfinite(value) and 0 <= value <= 5):
            raise ValueError(f"{name}: expected 0..5, got {value!r}")
    lo, hi = (float(f) for f in frequency_hz)
    if not (np.isfinite(lo) and np.isfinite(hi) and 0 < lo <= hi <= 1000):
        raise ValueError(f"frequency_hz: expected 0 < low <= high <= 1000 Hz, got {frequency_hz}")
    if not (np.isfinite(frame_rate_hz) and 0 < frame_rate_hz <= 100_000):
        raise ValueError(f"frame_rate_hz: expected a positive rate, got {frame_rate_hz!r}")
    period = 1.0 / frame_rate_hz
    exposure = period if exposure_s is None else float(exposure_s)
    if not (np.isfinite(exposure) and 0 < exposure <= period * (1 + 1e-9)):
        raise ValueError(f"exposure_s: expected 0 < exposure <= one frame period ({period:g} s), "
                         f"got {exposure_s!r}")
    if not (isinstance(blur_steps, (int, np.integer)) and 1 <= blur_steps <= 64):
        raise ValueError(f"blur_steps: expected 1..64, got {blur_steps!r}")
    ref = n_frames // 2 if reference_frame is None else int(reference_frame)
    if not 0 <= ref < n_frames:
        raise ValueError(f"reference_frame: expected 0..{n_frames - 1}, got {reference_frame!r}")
    if rotation_deg is None:
        rotation_deg = float(np.degrees(amplitude_mm / 3 / 8.0))
    if not (np.isfinite(rotation_deg) and 0 <= rotation_deg <= 10):
        raise ValueError(f"rotation_deg: expected 0..10 degrees, got {rotation_deg!r}")

    rng = np.random.default_rng([seed, 25])
    n_waves = 3
    freq = rng.uniform(lo, hi, (6, n_waves))
    phase = rng.uniform(0, 2 * np.pi, (6, n_waves))
    weight = rng.uniform(0.5, 1.0, (6, n_waves))
    drift_dir = rng.standard_normal(3)
    drift_dir /= np.linalg.norm(drift_dir)

    step_times = (np.arange(blur_steps) + 0.5) / blur_steps * exposure
    times = np.arange(n_frames)[:, None] * period + step_times[None, :]

    def waves(tt):
        return np.einsum("cw,...cw->...c", weight,
                         np.cos(2 * np.pi * freq * np.asarray(tt)[..., None, None] + phase))

    # the scale from an RMS over a long window (the waves' own RMS, not this capture's)
    fine = np.linspace(0, 2.0, 20001)
    w = waves(fine)
    t_rms = np.sqrt(np.mean(np.sum(w[:, :3] ** 2, axis=-1)))
    r_rms = np.sqrt(np.mean(np.sum(w[:, 3:] ** 2, axis=-1)))
    raw = waves(times)
    t_ref = times[ref].mean()
    raw_ref = waves(t_ref)
    translation = amplitude_mm * (raw[..., :3] - raw_ref[:3]) / t_rms
    translation += drift_mm_s * (times - t_ref)[..., None] * drift_dir
    rotvec = np.radians(rotation_deg) * (raw[..., 3:] - raw_ref[3:]) / r_rms
    description = {
        "model": "tremor",
        "amplitude_mm": float(amplitude_mm),
        "rotation_deg": round(float(rotation_deg), 6),
        "frequency_hz": [lo, hi],
        "drift_mm_s": float(drift_mm_s),
        "seed": int(seed),
    }
    return Motion(times_s=times, rotvec_rad=rotvec, translation_mm=translation,
                  center_mm=np.asarray(center_mm, dtype=float).reshape(3),
                  reference_frame=ref, frame_rate_hz=float(frame_rate_hz),
                  exposure_s=exposure, description=description)


@dataclass
class Moved(Scene):
    """A scene carried by a rigid motion: ``X = R X₀ + t`` for every point ``X₀`` of `scene`.

    Normals turn with ``R``; albedo and surface parameters (the finger's ``u, v``) are those
    of the scene's own point, so a moving finger carries its print.

    Attributes
    ----------
    scene : Scene
        The scene at its reference pose.
    R : (3, 3) float64
        Rotation (world frame).
    t : (3,) float64
        Translation, world mm (:meth:`Motion.pose` folds the centre of rotation into it).
    """

    scene: Scene
    R: np.ndarray
    t: np.ndarray

    def intersect(self, origin, directions):
        o = (np.asarray(origin, dtype=float) - self.t) @ self.R  # R⁻¹ (o − t)
        d = np.asarray(directions, dtype=float) @ self.R
        return self.scene.intersect(o, d)

    def surface(self, xyz) -> SurfaceInfo:
        info = self.scene.surface((np.asarray(xyz, dtype=float) - self.t) @ self.R)
        return SurfaceInfo(info.normal @ self.R.T, info.albedo, info.params)

    def to_dict(self):
        return self.scene.to_dict()
