"""Projector pattern sets (multi-frequency PMP, Gray code + phase, Gray code + line shift), grid.

A :class:`PatternSet` is the small JSON-serialisable description of what the projector shows: for
each direction (``"x"`` encodes the panel column ``xp``, ``"y"`` the panel row ``yp``) a list of
:class:`Frequency` entries (``periods`` across the panel, ``steps`` phase shifts), plus the
phase-shift sign and offset, the phase origin, the panel size, the grey levels and an optional
gamma pre-compensation. The same spec decodes captures from other systems (e.g. 3-step with 16
periods plus a 1-period cue): set the entries, the sign and the offset accordingly.

Phase rule (``docs/conventions.md``): at panel coordinate ``u`` along an axis of ``size`` pixels a
frequency of ``n`` periods has phase

    ``phi(u) = 2 pi n (u - origin) / size``,  ``origin = -1/2`` by default,

and step ``k`` of ``N`` shows ``1/2 + 1/2 cos(phi - delta_k)`` with the shift
``delta_k = sign * 2 pi k / N + offset`` (``sign = +1``, ``offset = 0`` by default). Frames are
ordered direction by direction (in the order of :attr:`PatternSet.directions`), frequency by
frequency (in the order listed), step by step; :func:`frame_table` says which frame is which.

Other schemes (``scheme``, :mod:`nail2nail.scan.gray`): ``"gray-phase"``, Gray code plus phase
shifting (one sinusoid per direction whose period index the Gray-code bit planes give, with the
complementary Gray-code bit by default), and ``"gray"``, Gray code plus line shifting (Gühring
2001: the Gray code numbers stripes ``w`` px wide, ``w`` frames of one-pixel lines shifted by
one pixel locate the position inside the stripe). Gray-code stripes follow the same panel
convention as the phase: stripe ``k`` of width ``T`` covers ``k T <= u - origin < (k + 1) T``
for pixel-centre coordinates ``u`` (``u = 0`` the centre of column 0; the default origin
``-1/2`` is the panel's physical edge). Frame order of a direction: the Gray-code bits (most
significant first, each followed by its inverse with ``reference="inverse"``), the
complementary bit, then the phase steps or the line frames; with ``reference="pair"`` an
all-lit and an all-dark frame open the whole sequence. ``"gray-code"``: the Gray-code bit planes
alone (as SLStudio's Gray codec, or structured-light systems that drop the finest bits):
entries ``(size / w, 1)`` give stripes ``w`` px wide (any width, 1 px and up), one frame per bit,
no fine frames; decoded to the stripe centres, so the coordinate is quantised to ``w``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np

from nail2nail._validation import as_int_pair
from nail2nail.scan.codes import code_profile, line_profile, n_code_bits

__all__ = [
    "DIRECTIONS",
    "SCHEMES",
    "FrameInfo",
    "Frequency",
    "PatternSet",
    "default_pattern_set",
    "frame_labels",
    "frame_table",
    "fringe_periods",
    "gray_code_pattern_set",
    "gray_line_pattern_set",
    "gray_phase_pattern_set",
    "grid_pattern",
    "make_patterns",
    "pattern_phase",
    "stripe_width",
]

DIRECTIONS = ("x", "y")
PANEL_SIZE = (1280, 1040)  # (W, H)
_FORMAT = "nail2nail-patterns"
#: Pattern schemes: multi-frequency PMP, Gray code + phase shifting, Gray code + line shifting.
SCHEMES = ("pmp", "gray-phase", "gray", "gray-code")
_REFERENCES = {"pmp": (None,), "gray-phase": ("mean", "pair", "inverse"),
               "gray": ("pair", "inverse"), "gray-code": ("pair", "inverse")}


@dataclass(frozen=True)
class Frequency:
    """One sinusoid of a direction: ``periods`` across the panel, shown in ``steps`` phase shifts.

    Parameters
    ----------
    periods : float
        Number of periods across the panel axis (> 0; the coarsest of a direction must be <= 1 so
        that temporal unwrapping is unambiguous).
    steps : int
        Number of phase shifts (>= 3).
    """

    periods: float
    steps: int

    def __post_init__(self) -> None:
        if isinstance(self.steps, bool) or not isinstance(self.steps, (int, np.integer)):
            raise TypeError(f"steps: expected an integer, got {type(self.steps).__name__}")
        if self.steps < 1:  # the schemes' own minimum: PatternSet
            raise ValueError(f"steps: expected at least 1, got {self.steps}")
        if not (isinstance(self.periods, (int, float, np.number)) and math.isfinite(self.periods)):
            raise TypeError(f"periods: expected a finite number, got {self.periods!r}")
        if self.periods <= 0:
            raise ValueError(f"periods: expected > 0, got {self.periods}")
        object.__setattr__(self, "periods", float(self.periods))
        object.__setattr__(self, "steps", int(self.steps))


@dataclass(frozen=True)
class FrameInfo:
    """What one frame of a pattern set shows (a row of :func:`frame_table`).

    ``kind`` is ``"phase"`` (a phase step; ``shift`` is ``delta_k`` in radians), ``"gray"``,
    ``"gray-inverse"``, ``"complementary"``, ``"complementary-inverse"`` (Gray-code bit plane
    ``bit``, most significant first; the complementary bit is ``bit = n_bits``), ``"line"``
    (line-shift frame ``step`` of ``steps``), ``"white"`` or ``"black"`` (``direction`` None).
    """

    index: int
    direction: str | None
    periods: float
    step: int
    steps: int
    shift: float  # delta_k in radians (phase frames; 0 otherwise)
    kind: str = "phase"
    bit: int = -1


def _as_frequencies(value, name: str) -> tuple[Frequency, ...]:
    if value is None:
        return ()
    if isinstance(value, (str, bytes)) or not isinstance(value, Iterable):
        raise TypeError(f"{name}: expected a list of frequencies, got {type(value).__name__}")
    out = []
    for item in value:
        if isinstance(item, Frequency):
            out.append(item)
        elif isinstance(item, Mapping):
            try:
                out.append(Frequency(item["periods"], item["steps"]))
            except KeyError as exc:
                raise ValueError(f"{name}: each frequency needs 'periods' and 'steps'") from exc
        else:
            try:
                periods, steps = item
            except (TypeError, ValueError) as exc:
                raise TypeError(
                    f"{name}: expected (periods, steps) pairs or Frequency, got {item!r}"
                ) from exc
            out.append(Frequency(periods, steps))
    return tuple(out)


@dataclass(frozen=True)
class PatternSet:
    """Description of a multi-frequency PMP pattern sequence (JSON-serialisable).

    Parameters
    ----------
    x, y : sequence of Frequency or (periods, steps) pairs
        Frequencies of the patterns varying along panel columns (encode ``xp``) and along panel
        rows (encode ``yp``). Either may be empty, not both.
    shift_sign : {+1, -1}
        Sign of the phase shift ``delta_k = shift_sign * 2 pi k / N + phase_offset``.
    phase_offset : float
        Constant added to every shift, radians.
    phase_origin : float
        Panel coordinate where the phase is zero; ``-0.5`` (the panel's physical edge) by default.
    panel_size : (int, int)
        Panel ``(W, H)`` in pixels; ``(1280, 1040)`` by default.
    levels : (int, int)
        8-bit grey levels of the sinusoid's minimum and maximum (``(0, 255)``).
    gamma : float or None
        Projector gamma to pre-compensate: the pattern value ``v`` in ``[0, 1]`` is sent as
        ``v ** (1 / gamma)``. ``None`` (default): linear.
    directions : tuple of str
        Order of the directions in the frame sequence; by default ``("x", "y")`` restricted to the
        non-empty ones.
    scheme : {"pmp", "gray-phase", "gray"}
        ``"pmp"`` (default): multi-frequency phase shifting. ``"gray-phase"``: one frequency per
        direction (``n`` periods, ``N`` steps) and ``ceil(log2 n)`` Gray-code bits giving its
        period index. ``"gray"``: one entry per direction ``(size / w, w)``: Gray code of stripes
        ``w`` px wide and ``w`` line-shift frames (``steps`` is the line spacing ``w`` and
        ``periods`` must be ``size / w``). See :mod:`nail2nail.scan.gray`.
    complementary : bool
        Gray-code schemes: add the complementary Gray-code bit (stripes half a period wide,
        edges half a period off the others') against one-period errors at code edges.
    reference : {"mean", "pair", "inverse"} or None
        Gray-code schemes: what a code bit is thresholded against: the mean of the phase frames
        (``"gray-phase"`` only; its default), an all-lit and an all-dark frame (``"pair"``,
        two frames first in the sequence; the default of ``"gray"``), or each bit's inverse
        pattern (``"inverse"``, one more frame per bit). ``None`` for PMP.
    """

    x: tuple[Frequency, ...] = ()
    y: tuple[Frequency, ...] = ()
    shift_sign: int = 1
    phase_offset: float = 0.0
    phase_origin: float = -0.5
    panel_size: tuple[int, int] = PANEL_SIZE
    levels: tuple[int, int] = (0, 255)
    gamma: float | None = None
    directions: tuple[str, ...] = field(default=())
    scheme: str = "pmp"
    complementary: bool = True
    reference: str | None = None

    def __post_init__(self) -> None:
        x = _as_frequencies(self.x, "x")
        y = _as_frequencies(self.y, "y")
        for f in (*x, *y):
            if self.scheme == "gray" and f.steps < 3:
                raise ValueError(f"steps: a 'gray' (line-shift) pattern set's steps are its line "
                                 f"spacing, at least 3 panel px (got {f.steps})")
            if self.scheme == "gray-code" and f.steps != 1:
                raise ValueError(f"steps: a 'gray-code' pattern set takes (size / w, 1) entries "
                                 f"(stripes of w px, one frame per code bit, no fine frames), "
                                 f"got steps {f.steps}")
            if self.scheme not in ("gray", "gray-code") and f.steps < 3:
                raise ValueError(f"steps: expected at least 3 phase steps, got {f.steps}")
        object.__setattr__(self, "x", x)
        object.__setattr__(self, "y", y)
        if not x and not y:
            raise ValueError("pattern set: at least one of x and y needs frequencies")
        if self.shift_sign not in (1, -1):
            raise ValueError(f"shift_sign: expected +1 or -1, got {self.shift_sign!r}")
        object.__setattr__(self, "shift_sign", int(self.shift_sign))
        for name in ("phase_offset", "phase_origin"):
            value = getattr(self, name)
            if not isinstance(value, (int, float, np.number)) or not math.isfinite(value):
                raise TypeError(f"{name}: expected a finite number, got {value!r}")
            object.__setattr__(self, name, float(value))
        width, height = as_int_pair(self.panel_size, "panel_size", "(W, H)", error=TypeError)
        if width < 1 or height < 1:
            raise ValueError(f"panel_size: expected positive (W, H), got {self.panel_size!r}")
        object.__setattr__(self, "panel_size", (width, height))
        low, high = as_int_pair(self.levels, "levels", "(low, high)", error=TypeError)
        if not 0 <= low < high <= 255:
            raise ValueError(f"levels: expected 0 <= low < high <= 255, got {self.levels!r}")
        object.__setattr__(self, "levels", (low, high))
        if self.gamma is not None:
            if (not isinstance(self.gamma, (int, float, np.number)) or isinstance(self.gamma, bool)
                    or not 0 < self.gamma < math.inf):
                raise ValueError(f"gamma: expected a positive number or None, got {self.gamma!r}")
            object.__setattr__(self, "gamma", float(self.gamma))
        present = tuple(d for d in DIRECTIONS if getattr(self, d))
        directions = tuple(self.directions) if self.directions else present
        if sorted(directions) != sorted(present):
            raise ValueError(
                f"directions: expected an order of {present} (the non-empty directions), "
                f"got {directions!r}"
            )
        object.__setattr__(self, "directions", directions)
        if self.scheme not in SCHEMES:
            raise ValueError(f"scheme: expected one of {SCHEMES}, got {self.scheme!r}")
        if not isinstance(self.complementary, (bool, np.bool_)):
            raise TypeError(f"complementary: expected a bool, got {self.complementary!r}")
        # no fine frames whose period errors a complementary bit would correct
        object.__setattr__(self, "complementary",
                           bool(self.complementary) and self.scheme != "gray-code")
        reference = self.reference
        if reference is None and self.scheme != "pmp":
            reference = _REFERENCES[self.scheme][0]
        if reference not in _REFERENCES[self.scheme]:
            raise ValueError(f"reference: expected one of {_REFERENCES[self.scheme]} for scheme "
                             f"{self.scheme!r}, got {self.reference!r}")
        object.__setattr__(self, "reference", reference)
        if self.scheme != "pmp":
            self._check_gray()
            return
        for d in present:
            coarsest = min(f.periods for f in getattr(self, d))
            if coarsest > 1.0:
                raise ValueError(
                    f"{d}: the coarsest frequency must have at most 1 period across the panel "
                    f"for unambiguous unwrapping, got {coarsest:g}"
                )

    def _check_gray(self) -> None:
        for d in self.directions:
            freqs = getattr(self, d)
            if len(freqs) != 1:
                raise ValueError(f"{d}: scheme {self.scheme!r} takes one (periods, steps) entry "
                                 f"per direction, got {len(freqs)}")
            size = self.axis_size(d)
            if self.scheme == "gray" and abs(freqs[0].periods * freqs[0].steps - size) > 1e-6:
                raise ValueError(
                    f"{d}: scheme 'gray' takes (size / w, w) with the line spacing w = steps; "
                    f"expected periods {size / freqs[0].steps:g} for steps {freqs[0].steps}, "
                    f"got {freqs[0].periods:g}")
            if self.scheme == "gray-phase" and freqs[0].periods < 1.0:
                raise ValueError(f"{d}: scheme 'gray-phase' needs at least 1 period, got "
                                 f"{freqs[0].periods:g}")

    # -- sizes ---------------------------------------------------------------------------------
    @property
    def n_frames(self) -> int:
        """Total number of frames."""
        if self.scheme == "pmp":
            return sum(f.steps for d in self.directions for f in getattr(self, d))
        return len(frame_table(self))

    def axis_size(self, direction: str) -> int:
        """Panel pixels along the axis a direction encodes (W for ``"x"``, H for ``"y"``)."""
        _check_direction(direction)
        return self.panel_size[0] if direction == "x" else self.panel_size[1]

    def frequencies(self, direction: str) -> tuple[Frequency, ...]:
        """The frequencies of one direction, in frame order."""
        _check_direction(direction)
        return getattr(self, direction)

    def shifts(self, steps: int) -> np.ndarray:
        """Phase shifts ``delta_k`` (radians, float64) of an ``steps``-step sequence."""
        k = np.arange(steps, dtype=np.float64)
        return self.shift_sign * 2.0 * np.pi * k / steps + self.phase_offset

    # -- JSON ----------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """A JSON-serialisable dict (``from_dict`` inverts it); ``scheme`` is written always,
        ``complementary`` and ``reference`` for the Gray-code schemes (a dict without
        ``scheme``, e.g. an older file, is PMP)."""
        gray = {} if self.scheme == "pmp" else {"complementary": self.complementary,
                                                 "reference": self.reference}
        return {
            "format": _FORMAT,
            "version": 1,
            "panel_size": list(self.panel_size),
            "directions": list(self.directions),
            "x": [{"periods": f.periods, "steps": f.steps} for f in self.x],
            "y": [{"periods": f.periods, "steps": f.steps} for f in self.y],
            "shift_sign": self.shift_sign,
            "phase_offset": self.phase_offset,
            "phase_origin": self.phase_origin,
            "levels": list(self.levels),
            "gamma": self.gamma,
            "scheme": self.scheme,
            **gray,
        }

    @classmethod
    def from_dict(cls, data: Mapping) -> PatternSet:
        """Build a pattern set from :meth:`to_dict` output (missing keys take their defaults)."""
        if not isinstance(data, Mapping):
            raise TypeError(f"pattern set: expected a mapping, got {type(data).__name__}")
        fmt = data.get("format", _FORMAT)
        if fmt != _FORMAT:
            raise ValueError(f"pattern set: expected format {_FORMAT!r}, got {fmt!r}")
        known = {"format", "version", "panel_size", "directions", "x", "y", "shift_sign",
                 "phase_offset", "phase_origin", "levels", "gamma", "scheme", "complementary",
                 "reference"}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"pattern set: unknown key(s) {unknown}")
        kwargs = {k: data[k] for k in known - {"format", "version"} if k in data}
        for key in ("panel_size", "levels", "directions"):
            if key in kwargs:
                kwargs[key] = tuple(kwargs[key])
        return cls(**kwargs)

    def to_json(self) -> str:
        """The spec as a JSON string."""
        return json.dumps(self.to_dict(), indent=2)

    @classmethod
    def from_json(cls, text: str) -> PatternSet:
        """Parse :meth:`to_json` output."""
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ValueError(f"pattern set: invalid JSON ({exc})") from exc
        return cls.from_dict(data)


def _check_direction(direction: str) -> None:
    if direction not in DIRECTIONS:
        raise ValueError(f"direction: expected 'x' or 'y', got {direction!r}")


def default_pattern_set(*, gamma: float | None = 2.2) -> PatternSet:
    """The default capture: 24 frames, ``x`` then ``y``, each 1 (3 steps), 8 (3), 64 (6) periods.

    Noise analysis (used to choose it; the decoder is :func:`nail2nail.scan.decoding.decode`). With
    intensity noise ``sigma`` (fraction of full scale; 8-bit quantisation alone gives
    ``1/(255 sqrt 12) = 0.0011``; the virtual scanner's shot noise at 20000 electrons full scale
    adds ``sqrt(I / 20000)``, 0.0034 at ``I = 0.23``) and sinusoid amplitude ``B``, an ``N``-step
    phase has standard deviation ``sigma_phi = sqrt(2/N) sigma / B``. The finest frequency sets
    the precision: a coordinate error ``sigma_u = sigma_phi * size / (2 pi n)``; with ``n = 64`` the
    period is 20 px in x (16.25 px in y), so ``sigma_u = 3.2 sigma_phi`` and ``N = 6`` gives
    ``sigma_u = 1.8 sigma / B``: ``sigma / B = 0.018`` (``B = 0.2``, albedo 0.5 under a projector
    of power 0.85) yields 0.033 px in x, 0.027 px in y, inside the 0.05 px target with margin for
    defocus (a Gaussian blur of ``s`` px scales ``B`` by ``exp(-2 pi^2 s^2 / T^2)``, 0.95 for
    ``s = 1``, ``T = 20``). Unwrapping a level of ratio ``r = 8`` fails when the coarser phase,
    scaled by ``r``, errs by more than ``pi`` (flagged beyond ``pi / 2``): with 3 steps the scaled
    noise is ``8 * 0.82 * 0.018 = 0.12`` rad, a 13-sigma margin to ``pi / 2``. Three steps are
    blind to the 2nd harmonic that a projector gamma creates (0.29 rad phase error for an
    uncompensated gamma 2.2, too much once scaled by 8), hence the gamma pre-compensation; a gamma
    wrong by 10 % leaves 0.03 rad. More periods would shrink ``sigma_u`` but lose modulation to
    defocus; fewer levels (1, 64) would make unwrapping fragile.

    Parameters
    ----------
    gamma : float or None
        Projector gamma to pre-compensate (2.2, the virtual scanner's); ``None`` for a linear
        projector.

    Returns
    -------
    PatternSet

    Examples
    --------
    >>> default_pattern_set().n_frames
    24
    """
    levels = (Frequency(1, 3), Frequency(8, 3), Frequency(64, 6))
    return PatternSet(x=levels, y=levels, gamma=gamma)


def frame_table(pattern_set: PatternSet) -> list[FrameInfo]:
    """Which direction, frequency and step every frame shows, in frame order.

    Examples
    --------
    >>> table = frame_table(default_pattern_set())
    >>> len(table), table[3].direction, table[3].periods, table[3].step
    (24, 'x', 8.0, 0)
    """
    _check_pattern_set(pattern_set)
    rows: list[FrameInfo] = []
    if pattern_set.scheme == "pmp":
        for direction in pattern_set.directions:
            for freq in pattern_set.frequencies(direction):
                for k, delta in enumerate(pattern_set.shifts(freq.steps)):
                    rows.append(
                        FrameInfo(len(rows), direction, freq.periods, k, freq.steps, float(delta))
                    )
        return rows

    inverse = pattern_set.reference == "inverse"
    if pattern_set.reference == "pair":
        rows.append(FrameInfo(0, None, 0.0, 0, 0, 0.0, kind="white"))
        rows.append(FrameInfo(1, None, 0.0, 0, 0, 0.0, kind="black"))
    for direction in pattern_set.directions:
        (freq,) = pattern_set.frequencies(direction)
        n_stripes = pattern_set.axis_size(direction) / stripe_width(pattern_set, direction)
        n_bits = n_code_bits(n_stripes)
        planes = [("gray", b) for b in range(n_bits)]
        if pattern_set.complementary and pattern_set.scheme != "gray-code":
            planes.append(("complementary", n_bits))
        for kind, bit in planes:
            rows.append(FrameInfo(len(rows), direction, freq.periods, 0, 0, 0.0, kind=kind,
                                  bit=bit))
            if inverse:
                rows.append(FrameInfo(len(rows), direction, freq.periods, 0, 0, 0.0,
                                      kind=f"{kind}-inverse", bit=bit))
        if pattern_set.scheme == "gray-code":
            continue  # the code alone
        if pattern_set.scheme == "gray-phase":
            for k, delta in enumerate(pattern_set.shifts(freq.steps)):
                rows.append(FrameInfo(len(rows), direction, freq.periods, k, freq.steps,
                                      float(delta)))
        else:
            for k in range(freq.steps):
                rows.append(FrameInfo(len(rows), direction, freq.periods, k, freq.steps, 0.0,
                                      kind="line"))
    return rows


def stripe_width(pattern_set: PatternSet, direction: str) -> float:
    """Width ``T`` (panel px) of a direction's finest code stripe or period: ``size / periods``
    of its finest frequency (for ``"gray"``, the line spacing ``w``).

    Examples
    --------
    >>> stripe_width(gray_phase_pattern_set(), "x"), stripe_width(gray_line_pattern_set(), "y")
    (20.0, 8.0)
    """
    _check_pattern_set(pattern_set)
    finest = max(f.periods for f in pattern_set.frequencies(direction))
    return pattern_set.axis_size(direction) / finest


def fringe_periods(pattern_set: PatternSet) -> dict[str, float]:
    """The period (panel px) of each direction's finest fringes: what the decoded coordinate's
    systematic error repeats with (:mod:`nail2nail.unroll.fringes`).

    :func:`stripe_width` of every direction of a phase scheme (``"pmp"``, ``"gray-phase"``,
    ``"gray"``'s line shift); empty for ``"gray-code"``, which has no phase.

    Examples
    --------
    >>> fringe_periods(default_pattern_set())
    {'x': 20.0, 'y': 16.25}
    """
    _check_pattern_set(pattern_set)
    if pattern_set.scheme == "gray-code":
        return {}
    return {d: stripe_width(pattern_set, d) for d in pattern_set.directions}


def gray_phase_pattern_set(*, periods: float = 64, steps: int = 4, complementary: bool = True,
                           reference: str = "mean", panel_size=PANEL_SIZE,
                           directions=("x", "y"), gamma: float | None = 2.2) -> PatternSet:
    """Gray code plus phase shifting (GCPS), the same in each direction.

    Parameters
    ----------
    periods, steps : float, int
        The sinusoid: periods across the panel and phase steps (64 and 4 by default:
        ``ceil(log2 64) = 6`` code bits, one complementary bit).
    complementary : bool
        Add the complementary Gray-code bit.
    reference : {"mean", "pair", "inverse"}
        Threshold of the code bits (:class:`PatternSet`).
    panel_size : (int, int)
    directions : tuple of str
        ``("x", "y")``, ``("x",)`` or ``("y",)``.
    gamma : float or None
        Projector gamma to pre-compensate.

    Examples
    --------
    >>> gray_phase_pattern_set().n_frames
    22
    """
    entry = (Frequency(periods, steps),)
    return PatternSet(x=entry if "x" in directions else (), y=entry if "y" in directions else (),
                      directions=tuple(directions), panel_size=panel_size, gamma=gamma,
                      scheme="gray-phase", complementary=complementary, reference=reference)


def gray_line_pattern_set(*, spacing: int = 8, complementary: bool = True,
                          reference: str = "pair", panel_size=PANEL_SIZE,
                          directions=("x", "y"), gamma: float | None = 2.2) -> PatternSet:
    """Gray code plus line shifting (Gühring 2001), the same line spacing in each direction.

    Parameters
    ----------
    spacing : int
        Line spacing ``w`` = stripe width of the code = number of line frames (8 by default:
        8 code bits for the 160 stripes of 1280 px, one complementary bit, 8 line frames).
    complementary, reference, panel_size, directions, gamma
        As :func:`gray_phase_pattern_set` (``reference`` ``"pair"`` or ``"inverse"``).

    Examples
    --------
    >>> gray_line_pattern_set().n_frames
    36
    """
    width, height = as_int_pair(panel_size, "panel_size", "(W, H)", error=TypeError)
    spacing = int(spacing)
    if spacing < 3:
        raise ValueError(f"spacing: expected at least 3 px, got {spacing}")
    return PatternSet(x=(Frequency(width / spacing, spacing),) if "x" in directions else (),
                      y=(Frequency(height / spacing, spacing),) if "y" in directions else (),
                      directions=tuple(directions), panel_size=(width, height), gamma=gamma,
                      scheme="gray", complementary=complementary, reference=reference)


def gray_code_pattern_set(*, stripe: float = 2.0, reference: str = "pair",
                          panel_size=PANEL_SIZE, directions=("x", "y"),
                          gamma: float | None = None) -> PatternSet:
    """Gray code alone: stripes `stripe` px wide numbered by their Gray-code bit planes.

    Parameters
    ----------
    stripe : float
        Stripe width ``w``, panel px (1 and up; 2 is SLStudio's codec, whose 11-bit column
        codes leave the least significant bit out). ``ceil(log2(size / w))`` bit planes per
        direction.
    reference : {"pair", "inverse"}
        An all-lit and an all-dark frame first (default), or every bit followed by its inverse.
    panel_size, directions
        As :func:`gray_phase_pattern_set`.
    gamma : float or None
        Binary patterns need no gamma pre-compensation (default None).

    Examples
    --------
    >>> ps = gray_code_pattern_set(panel_size=(1824, 1140), directions=("x",))
    >>> ps.n_frames, frame_table(ps)[2].kind
    (12, 'gray')
    """
    width, height = as_int_pair(panel_size, "panel_size", "(W, H)", error=TypeError)
    stripe = float(stripe)
    if not (math.isfinite(stripe) and stripe >= 1):
        raise ValueError(f"stripe: expected a width of at least 1 px, got {stripe}")
    return PatternSet(x=(Frequency(width / stripe, 1),) if "x" in directions else (),
                      y=(Frequency(height / stripe, 1),) if "y" in directions else (),
                      directions=tuple(directions), panel_size=(width, height), gamma=gamma,
                      scheme="gray-code", complementary=False, reference=reference)


def frame_labels(pattern_set: PatternSet) -> list[str]:
    """What every frame shows, one short label a frame, in frame order (:func:`frame_table`).

    Examples
    --------
    >>> frame_labels(default_pattern_set())[:2]
    ['x: 1 period, step 1/3', 'x: 1 period, step 2/3']
    """
    labels = []
    for info in frame_table(pattern_set):
        if info.kind == "phase":
            unit = "period" if info.periods == 1 else "periods"
            labels.append(f"{info.direction}: {info.periods:g} {unit}, step "
                          f"{info.step + 1}/{info.steps}")
        elif info.kind == "line":
            labels.append(f"{info.direction}: line {info.step + 1}/{info.steps}")
        elif info.direction is None:
            labels.append(info.kind)
        else:
            labels.append(f"{info.direction}: {info.kind} bit {info.bit}")
    return labels


def _check_pattern_set(pattern_set) -> None:
    if not isinstance(pattern_set, PatternSet):
        raise TypeError(f"pattern_set: expected a PatternSet, got {type(pattern_set).__name__}")


def pattern_phase(pattern_set: PatternSet, direction: str, periods: float, u) -> np.ndarray:
    """Unwrapped phase ``2 pi n (u - origin) / size`` at panel coordinate(s) ``u`` (radians).

    Examples
    --------
    >>> float(pattern_phase(default_pattern_set(), "x", 1, 639.5) / np.pi)
    1.0
    """
    _check_pattern_set(pattern_set)
    size = pattern_set.axis_size(direction)
    u = np.asarray(u, dtype=np.float64)
    return 2.0 * np.pi * periods * (u - pattern_set.phase_origin) / size


def _to_levels(value: np.ndarray, pattern_set: PatternSet) -> np.ndarray:
    """Map pattern values in ``[0, 1]`` to 8-bit grey levels (gamma, levels, rounding)."""
    if pattern_set.gamma is not None:
        value = np.clip(value, 0.0, 1.0) ** (1.0 / pattern_set.gamma)
    low, high = pattern_set.levels
    return np.rint(low + (high - low) * value).astype(np.uint8)


def make_patterns(pattern_set: PatternSet) -> np.ndarray:
    """Render every frame of a pattern set as 8-bit panel images.

    Parameters
    ----------
    pattern_set : PatternSet

    Returns
    -------
    frames : (n_frames, Hp, Wp) uint8
        Frame ``i`` is described by ``frame_table(pattern_set)[i]``.

    Examples
    --------
    >>> frames = make_patterns(PatternSet(x=[(1, 3)], panel_size=(8, 2)))
    >>> frames.shape, frames.dtype.name
    ((3, 2, 8), 'uint8')
    >>> frames[0, 0].tolist()
    [245, 176, 79, 10, 10, 79, 176, 245]
    """

    _check_pattern_set(pattern_set)
    width, height = pattern_set.panel_size
    table = frame_table(pattern_set)
    out = np.empty((len(table), height, width), dtype=np.uint8)
    for info in table:
        if info.kind in ("white", "black"):
            out[info.index] = _to_levels(np.asarray(float(info.kind == "white")), pattern_set)
            continue
        assert info.direction is not None  # every frame but the all-lit and all-dark has one
        size = pattern_set.axis_size(info.direction)
        u = np.arange(size)
        if info.kind == "phase":
            phase = pattern_phase(pattern_set, info.direction, info.periods, u)
            value = 0.5 + 0.5 * np.cos(phase - info.shift)
        elif info.kind == "line":
            value = line_profile(u, pattern_set.phase_origin, info.steps, info.step)
        else:
            stripe = stripe_width(pattern_set, info.direction)
            value = code_profile(u, pattern_set.phase_origin, stripe,
                                 n_code_bits(size / stripe), info.bit)
            if info.kind.endswith("-inverse"):
                value = 1 - value
        profile = _to_levels(np.asarray(value, dtype=np.float64), pattern_set)
        if info.direction == "x":
            out[info.index] = profile[None, :]
        else:
            out[info.index] = profile[:, None]
    return out


def grid_pattern(
    *,
    panel_size: tuple[int, int] = PANEL_SIZE,
    spacing: int = 64,
    width: int = 1,
    offset: tuple[int, int] | None = None,
    foreground: int = 255,
    background: int = 0,
) -> np.ndarray:
    """A grid of thin lines on the panel, for projector distortion estimation (thesis §3.2).

    Parameters
    ----------
    panel_size : (int, int)
        Panel ``(W, H)``.
    spacing : int
        Distance between neighbouring lines, panel px (> width).
    width : int
        Line width, panel px (>= 1).
    offset : (int, int) or None
        Panel ``(x, y)`` of one vertical and one horizontal line; by default the panel centre
        ``(W // 2, H // 2)`` so that the grid is symmetric.
    foreground, background : int
        8-bit levels of the lines and of the rest.

    Returns
    -------
    grid : (Hp, Wp) uint8
        Line pixels are columns ``c`` with ``(c - offset_x) mod spacing < width`` and rows likewise.

    Examples
    --------
    >>> g = grid_pattern(panel_size=(8, 6), spacing=4, offset=(1, 2))
    >>> g[0].tolist()
    [0, 255, 0, 0, 0, 255, 0, 0]
    """
    try:
        w, h = (int(v) for v in panel_size)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"panel_size: expected (W, H), got {panel_size!r}") from exc
    if w < 1 or h < 1:
        raise ValueError(f"panel_size: expected positive (W, H), got {panel_size!r}")
    if width < 1 or spacing <= width:
        raise ValueError(
            f"spacing, width: expected width >= 1 and spacing > width, got {spacing}, {width}"
        )
    for name, value in (("foreground", foreground), ("background", background)):
        if not 0 <= int(value) <= 255:
            raise ValueError(f"{name}: expected an 8-bit level 0..255, got {value}")
    ox, oy = (w // 2, h // 2) if offset is None else (int(offset[0]), int(offset[1]))
    cols = (np.arange(w) - ox) % spacing < width
    rows = (np.arange(h) - oy) % spacing < width
    grid = np.full((h, w), background, dtype=np.uint8)
    grid[rows[:, None] | cols[None, :]] = foreground
    return grid
