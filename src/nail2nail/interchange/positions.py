"""The code tables of ANSI/NIST-ITL that a fingerprint transaction's Type-14 records use.

From ANSI/NIST-ITL 1-2011 Update:2015 (NIST SP 500-290 Edition 3): the friction ridge
impression types (Table 8 of that edition; Table 7 of the 2011 edition), the finger positions
(Table 9; Table 8 in 2011) and the compression algorithm labels of tagged-field records (Table
19; Table 15 in 2011). Update:2015 renamed the impression codes and kept four for contactless
capture, the codes NIST SP 500-334 (contactless capture best practice, revised 2024) asks
contactless images to carry: 24 and 25 (plain and rolled, stationary subject), 41 and 42
(rolled and plain, moving subject). The codes it made legacy (2, 3, 5–7, 10–23, 26, 27,
30–39) are not listed. ``docs/interchange.md`` lists what is written and from where.
"""

from __future__ import annotations

__all__ = [
    "COMPRESSION_LABELS",
    "CONTACTLESS_IMPRESSIONS",
    "FINGER_POSITIONS",
    "IMPRESSION_TYPES",
    "ROLLED_CONTACTLESS_STATIONARY",
    "SINGLE_FINGER_POSITIONS",
    "check_impression",
    "check_position",
]

#: Friction ridge impression types of Update:2015 that are not legacy (code: description).
IMPRESSION_TYPES = {
    0: "plain contact",
    1: "rolled contact",
    4: "latent image or impression",
    8: "finger swiped on platen",
    24: "plain contactless, stationary subject",
    25: "rolled contactless, stationary subject",
    28: "other",
    29: "unknown",
    41: "rolled contactless, moving subject",
    42: "plain contactless, moving subject",
}

#: The contactless impression types; nail2nail writes one of them, never a contact code.
CONTACTLESS_IMPRESSIONS = (24, 25, 41, 42)

#: nail2nail's print: a rolled-equivalent print of a finger held still in the scanner.
ROLLED_CONTACTLESS_STATIONARY = 25

#: Finger positions 0–19 of the friction ridge position table (20–38 are palms, 40–54 finger
#: combinations, 60–79 soles and toes, 81–86 further palm areas: none is a finger's print).
FINGER_POSITIONS = {
    0: "unknown finger",
    1: "right thumb",
    2: "right index finger",
    3: "right middle finger",
    4: "right ring finger",
    5: "right little finger",
    6: "left thumb",
    7: "left index finger",
    8: "left middle finger",
    9: "left ring finger",
    10: "left little finger",
    11: "plain right thumb",
    12: "plain left thumb",
    13: "plain right four fingers",
    14: "plain left four fingers",
    15: "left and right thumbs",
    16: "right extra digit",
    17: "left extra digit",
    18: "unknown friction ridge",
    19: "EJI or tip",
}

#: The positions of one finger's print: what a rolled-equivalent print can be.
SINGLE_FINGER_POSITIONS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 16, 17)

#: Compression algorithm labels of tagged-field image records (field 14.011 CGA).
COMPRESSION_LABELS = {
    "NONE": "uncompressed",
    "WSQ20": "WSQ (FBI IAFIS-IC-0110, version 2.0 or later), lossy",
    "JPEGB": "JPEG baseline, lossy",
    "JPEGL": "JPEG lossless",
    "JP2": "JPEG 2000, lossy",
    "JP2L": "JPEG 2000, lossless",
    "PNG": "PNG, lossless",
}


def _as_code(value, where: str) -> int:
    if isinstance(value, bool):
        raise TypeError(f"{where}: expected an integer code, got {value!r}")
    if isinstance(value, str) and value.strip().isdigit():
        return int(value)
    if isinstance(value, int):
        return value
    raise TypeError(f"{where}: expected an integer code, got {value!r}")


def check_position(value, where: str = "position") -> int:
    """A finger position of one finger's print, checked against the standard's table.

    Parameters
    ----------
    value : int or str
        The code (``"2"`` or ``2``).
    where : str
        What to name in the message (an option, a file and field).

    Returns
    -------
    int
        One of :data:`SINGLE_FINGER_POSITIONS`.

    Raises
    ------
    ValueError
        A code outside the table, or one of several fingers (11–15, 19) or of no finger (18).
    TypeError
        If `value` is not an integer code.

    Examples
    --------
    >>> check_position("7"), FINGER_POSITIONS[7]
    (7, 'left index finger')
    """
    code = _as_code(value, where)
    if code in SINGLE_FINGER_POSITIONS:
        return code
    allowed = "0-10 (0: unknown finger, 1-5 right thumb to little finger, 6-10 left), 16, 17"
    if code in FINGER_POSITIONS:
        raise ValueError(f"{where}: {code} ({FINGER_POSITIONS[code]}) is not the position of "
                         f"one finger's print; expected {allowed}")
    raise ValueError(f"{where}: {code} is not a finger position of ANSI/NIST-ITL 1-2011 "
                     f"Update:2015; expected {allowed}")


def check_impression(value, where: str = "impression") -> int:
    """A contactless impression type code (:data:`CONTACTLESS_IMPRESSIONS`).

    Raises
    ------
    ValueError
        A code that is not contactless, or not in the table.
    TypeError
        If `value` is not an integer code.

    Examples
    --------
    >>> check_impression(25), IMPRESSION_TYPES[25]
    (25, 'rolled contactless, stationary subject')
    """
    code = _as_code(value, where)
    if code in CONTACTLESS_IMPRESSIONS:
        return code
    named = f" ({IMPRESSION_TYPES[code]})" if code in IMPRESSION_TYPES else ""
    raise ValueError(f"{where}: {code}{named} is not a contactless impression type; expected "
                     "24, 25, 41 or 42")
