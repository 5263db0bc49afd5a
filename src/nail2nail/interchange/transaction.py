"""ANSI/NIST-ITL transactions of rolled-equivalent prints: build, write, read back.

A transaction holds one person's prints, up to one per finger position: a Type-1 record, an
optional Type-2 record of the user's fields (an application profile's: EBTS, Interpol) and one
Type-14 record per finger, in the traditional (binary) encoding of ANSI/NIST-ITL 1-2011
Update:2015 (version ``0502``). Records are built and parsed by IDEMIA's ``nistitl``; every
transaction is read back before it is written (:func:`read_transaction`). The images are the
prints' lossless PNGs compressed for the record: WSQ at 500 ppi (the FBI's codec, at a chosen
bit rate, 0.75 bpp by default), lossy JPEG 2000 at 1000 ppi. Fields, their sources and the
profile: ``docs/interchange.md``.
"""

from __future__ import annotations

import hashlib
import os
import re
import time
import uuid
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from nail2nail.interchange.jobs import FingerPrint, read_job
from nail2nail.interchange.positions import (
    COMPRESSION_LABELS,
    FINGER_POSITIONS,
    IMPRESSION_TYPES,
    ROLLED_CONTACTLESS_STATIONARY,
    check_impression,
    check_position,
)
from nail2nail.io._atomic import atomic_path, check_output_file
from nail2nail.io._json import read_json
from nail2nail.io.prints import (
    JPEG2000_RATIO,
    WSQ_BITRATE,
    WSQ_BITRATE_RANGE,
    decode_jpeg2000,
    decode_wsq,
    encode_jpeg2000,
    encode_wsq,
    wsq_shape,
)

__all__ = [
    "AGENCY_DEFAULT",
    "DEFAULT_TOT",
    "PPI_CHOICES",
    "QUALITY_ALGORITHM",
    "TEXT_MAX",
    "VERSION",
    "build_transaction",
    "export_transaction",
    "load_type2",
    "read_transaction",
]

#: Field 1.002 VER: ANSI/NIST-ITL 1-2011 Update:2015.
VERSION = "0502"
#: Transaction type (1.004 TOT) by default: nail2nail's own, so that a receiving system does
#: not take contactless prints for contact ones (SP 500-334); an application profile's TOT
#: (EBTS ``CAR``, …) is given with ``tot=``.
DEFAULT_TOT = "CONTACTLESS"
#: Originating and destination agency (1.008 ORI, 1.007 DAI, 14.004 SRC) by default: unknown
#: until the user names them (``ori=``, ``dai=``).
AGENCY_DEFAULT = "UNKNOWN"
#: Resolutions of a transaction's prints, ppi: WSQ is the FBI's codec at 500 ppi, lossy
#: JPEG 2000 the EBTS's at 1000 ppi; others are refused (run ``process --ppi`` again).
PPI_CHOICES = (500, 1000)
#: Longest free text written (agency identifiers, device items, comments), characters: the
#: standard's limit for comment fields (14.020 COM), ample for any agency identifier.
TEXT_MAX = 126
#: Longest transaction type (1.004 TOT), characters: the standard's limit.
TOT_MAX = 16
#: Quality algorithm of field 14.024 FQM: vendor 0000 and product 1 are placeholders, since
#: nail2nail has no vendor identifier registered with IBIA; the value is the print's ridge
#: clarity median × 100, not NFIQ 2.
QUALITY_ALGORITHM = ("0000", "1")

_FIELD_KEY = re.compile(r"^2\.(\d{3})$")


def _text(value, where: str, *, max_len: int = TEXT_MAX) -> str:
    """Printable ASCII (the standard's default character set), 1..max_len characters."""
    if not isinstance(value, str):
        raise TypeError(f"{where}: expected text, got {type(value).__name__}")
    if not value or len(value) > max_len:
        raise ValueError(f"{where}: expected 1 to {max_len} characters, got {len(value)} "
                         f"({value[:40]!r})")
    bad = [c for c in value if not 32 <= ord(c) <= 126]
    if bad:
        raise ValueError(f"{where}: {value[:40]!r} holds {bad[0]!r}; expected printable ASCII "
                         "(the standard's default character set, without separators)")
    return value


def _record_text(value, where: str) -> str:
    """Text of a Type-14 field: nistitl 0.6 finds field 14.999 by the first '999:' of the
    record, so that sequence is refused before the image."""
    value = _text(value, where)
    if "999:" in value:
        raise ValueError(f"{where}: {value!r} holds '999:', which ends a Type-14 record's "
                         "text for the reader (nistitl); rephrase it")
    return value


def _sanitised(text: str) -> str:
    """Our own description, fitted to a Type-14 text field (printable ASCII, TEXT_MAX)."""
    text = "".join(c if 32 <= ord(c) <= 126 else "?" for c in text).replace("999:", "999 :")
    return text[:TEXT_MAX]


def _normalised_value(value, where: str):
    """A Type-2 value as the traditional encoding gives it back: text, a list of subfields
    (text or a list of items); one-element lists are their element."""
    if isinstance(value, str):
        return _text(value, where, max_len=10_000)
    if isinstance(value, list) and value:
        subfields: list[str | list[str]] = []
        for i, sub in enumerate(value):
            if isinstance(sub, str):
                subfields.append(_text(sub, f"{where}[{i}]", max_len=10_000))
            elif isinstance(sub, list) and sub and all(isinstance(v, str) for v in sub):
                items = [_text(v, f"{where}[{i}][{j}]", max_len=10_000)
                         for j, v in enumerate(sub)]
                subfields.append(items[0] if len(items) == 1 else items)
            else:
                raise ValueError(f"{where}[{i}]: expected text or a non-empty list of texts, "
                                 f"got {sub!r:.60}")
        return subfields[0] if len(subfields) == 1 and isinstance(subfields[0], str) else (
            subfields)
    raise ValueError(f"{where}: expected text, a list of subfields or a list of lists of "
                     f"items, got {value!r:.60}")


def load_type2(source) -> dict[int, object]:
    """The user's Type-2 fields: ``{"2.018": "DOE, JOHN", "2.020": ["A", "B"], …}``.

    Keys are ``"2.NNN"`` with NNN 003–999 (2.001 and 2.002 are the record's length and IDC,
    written by nail2nail); values are text, a list of subfields, or a list of lists of items,
    printable ASCII. A one-element list is its element (the encoding cannot tell them apart).

    Parameters
    ----------
    source : path-like or dict
        A JSON file, or its content.

    Returns
    -------
    dict
        Field number → value, as it reads back.

    Raises
    ------
    ValueError
        Naming the file and the key.
    """
    where = os.fspath(source) if isinstance(source, (str, os.PathLike)) else "type2"
    data = read_json(source) if isinstance(source, (str, os.PathLike)) else source
    if not isinstance(data, dict) or not data:
        raise ValueError(f"{where}: expected a JSON object of Type-2 fields "
                         '{"2.NNN": value, …}, got '
                         f"{type(data).__name__ if not isinstance(data, dict) else 'none'}")
    fields: dict[int, object] = {}
    for key, value in data.items():
        match = _FIELD_KEY.match(key) if isinstance(key, str) else None
        if match is None:
            raise ValueError(f"{where}: {key!r} is not a Type-2 field number; expected "
                             "'2.NNN' (three digits, 003 to 999)")
        tag = int(match.group(1))
        if tag < 3:
            raise ValueError(f"{where}: {key!r} is written by nail2nail (2.001 length, 2.002 "
                             "IDC); give fields 2.003 to 2.999")
        fields[tag] = _normalised_value(value, f"{where}: {key}")
    return dict(sorted(fields.items()))


def _check_tot(tot, where: str) -> str:
    if not (isinstance(tot, str) and 1 <= len(tot) <= TOT_MAX and tot.isascii()
            and tot.isalpha()):
        raise ValueError(f"{where}: expected 1 to {TOT_MAX} letters, got {tot!r}")
    return tot


def _device_items(device, where: str = "device") -> list[str] | None:
    if device is None:
        return None
    if not isinstance(device, (list, tuple)) or len(device) != 3:
        raise ValueError(f"{where}: expected make, model and serial number, got {device!r}")
    return [_record_text(v, f"{where} {name}") for v, name in zip(
        device, ("make", "model", "serial number"), strict=True)]


def _encode(finger: FingerPrint, *, wsq_bitrate: float, jpeg2000_ratio: float
            ) -> tuple[str, bytes]:
    if round(finger.ppi) == 500:
        return "WSQ20", encode_wsq(finger.image, bitrate=wsq_bitrate)
    return "JP2", encode_jpeg2000(finger.image, ratio=jpeg2000_ratio)


def build_transaction(
    fingers: Sequence[tuple[int, FingerPrint]],
    *,
    type2: dict | None = None,
    impression: int = ROLLED_CONTACTLESS_STATIONARY,
    wsq_bitrate: float = WSQ_BITRATE,
    jpeg2000_ratio: float = JPEG2000_RATIO,
    tot: str = DEFAULT_TOT,
    ori: str = AGENCY_DEFAULT,
    dai: str = AGENCY_DEFAULT,
    tcn: str | None = None,
    device=None,
    when: float | None = None,
) -> tuple[bytes, dict]:
    """Encode one person's prints as an ANSI/NIST-ITL transaction.

    Parameters
    ----------
    fingers : sequence of (position, FingerPrint)
        Finger position (0–10, 16, 17; unique) and print, at 500 or 1000 ppi.
    type2 : dict, optional
        Type-2 fields, as :func:`load_type2` returns them.
    impression : int
        14.003 IMP, a contactless code: 25 (rolled, stationary subject) by default.
    wsq_bitrate : float
        WSQ bit rate of the 500 ppi prints, bits per pixel.
    jpeg2000_ratio : float
        JPEG 2000 compression ratio of the 1000 ppi prints.
    tot, ori, dai, tcn : str
        Type-1 transaction type, originating and destination agency, control number (a random
        UUID by default).
    device : (make, model, serial) of str, optional
        14.904 MMS of every print.
    when : float, optional
        POSIX time of the transaction (1.005 DAT, 1.014 GMT); now by default.

    Returns
    -------
    data : bytes
        The transaction.
    summary : dict
        ``{"version", "tot", "tcn", "bytes", "fields": {"type1", "type2", "type14": [...]},
        "prints": [{"idc", "position", "position_name", "compression", "ppi", "shape",
        "bytes", "compression_ratio", "bits_per_pixel", "quality", "source"}]}``; ``fields``
        holds every field written but the images (read back identical: the tests).

    Raises
    ------
    ValueError
        Bad positions (outside the table, not one finger's, repeated), no print, a print at
        another resolution than 500 or 1000 ppi, text that is not printable ASCII.
    """
    import nistitl

    fingers = list(fingers)
    if not fingers:
        raise ValueError("fingers: expected at least one print")
    impression = check_impression(impression, "impression")
    seen: dict[int, str] = {}
    for position, finger in fingers:
        position = check_position(position, "finger position")
        if position in seen:
            raise ValueError(f"finger position: {position} ({FINGER_POSITIONS[position]}) is "
                             f"given twice ({seen[position]} and {finger.source})")
        seen[position] = finger.source
        if round(finger.ppi) not in PPI_CHOICES or abs(finger.ppi - round(finger.ppi)) > 0.05:
            raise ValueError(f"{finger.source}: the print is at {finger.ppi:g} ppi; a "
                             "transaction takes 500 ppi (WSQ) or 1000 ppi (JPEG 2000): run "
                             "`nail2nail process … --ppi 500` again")
    tot = _check_tot(tot, "tot")
    ori, dai = _text(ori, "ori"), _text(dai, "dai")
    tcn = uuid.uuid4().hex if tcn is None else _text(tcn, "tcn", max_len=40)
    mms = _device_items(device)
    when = time.time() if when is None else float(when)

    msg = nistitl.Message()
    r1 = msg[0]
    type1 = {2: VERSION, 4: tot, 5: time.strftime("%Y%m%d", time.localtime(when)), 7: dai,
             8: ori, 9: tcn, 11: "00.00", 12: "00.00",
             14: time.strftime("%Y%m%d%H%M%SZ", time.gmtime(when))}
    for tag, text in type1.items():
        setattr(r1, f"_{tag}", text)
    type2_written = None
    if type2:
        r2 = nistitl.AsciiRecord(2)
        r2.IDC = 0
        for tag, content in type2.items():
            r2 += nistitl.Field(2, tag, content)
        msg += r2
        type2_written = {2: 0, **type2}
    records, prints = [], []
    ordered = sorted(fingers, key=lambda pf: int(pf[0]))
    for idc, (position, finger) in enumerate(ordered, start=1):
        position = int(position)
        label, data = _encode(finger, wsq_bitrate=wsq_bitrate, jpeg2000_ratio=jpeg2000_ratio)
        height, width = finger.image.shape
        ppi = str(round(finger.ppi))
        fields: dict[int, object] = {
            2: idc, 3: str(impression), 4: ori, 5: finger.capture_date, 6: str(width),
            7: str(height), 8: "1", 9: ppi, 10: ppi, 11: label, 12: "8", 13: str(position),
            20: _sanitised(finger.comment),
        }
        if finger.quality is not None:
            fields[24] = [[str(position), str(finger.quality), *QUALITY_ALGORITHM]]
        if mms is not None:
            fields[904] = [mms]
        fields[996] = hashlib.sha256(data).hexdigest()
        r14 = nistitl.AsciiRecord(14)
        for tag, value in fields.items():
            if tag == 2:
                r14.IDC = value
            else:
                r14 += nistitl.Field(14, tag, value)
        r14 += nistitl.BinaryField(14, 999, data)
        msg += r14
        records.append(fields)
        prints.append({
            "idc": idc, "position": position, "position_name": FINGER_POSITIONS[position],
            "impression": impression, "compression": label, "ppi": int(ppi),
            "shape": [height, width], "bytes": len(data),
            "compression_ratio": round(finger.image.size / len(data), 2),
            "bits_per_pixel": round(8.0 * len(data) / finger.image.size, 4),
            "wsq_bitrate_bpp": wsq_bitrate if label == "WSQ20" else None,
            "quality": finger.quality, "source": finger.source})
    data = msg.NIST
    summary = {"version": VERSION, "tot": tot, "tcn": tcn, "bytes": len(data),
               "fields": {"type1": type1, "type2": type2_written, "type14": records},
               "prints": prints}
    return data, summary


def _as_int(value, where: str) -> int:
    try:
        return int(str(value))
    except ValueError as exc:
        raise ValueError(f"{where}: expected an integer, got {value!r}") from exc


def _decode(label: str, data: bytes, shape: tuple[int, int], name: str) -> np.ndarray:
    if label == "WSQ20":
        return decode_wsq(data, name=name)
    if label in ("JP2", "JP2L"):
        return decode_jpeg2000(data, name=name)
    if label == "NONE":
        if len(data) != shape[0] * shape[1]:
            raise ValueError(f"{name}: {len(data)} bytes of uncompressed image data for "
                             f"{shape[1]} x {shape[0]} pixels")
        return np.frombuffer(data, np.uint8).reshape(shape).copy()
    raise ValueError(f"{name}: compression {label!r} is not read by nail2nail (WSQ20, JP2, "
                     "JP2L or NONE)")


def _stored_shape(label: str, data: bytes, name: str) -> tuple[int, int] | None:
    """The image's size from its header, without decoding (WSQ, JPEG 2000)."""
    if label == "WSQ20":
        try:
            return wsq_shape(data)
        except ValueError as exc:
            raise ValueError(f"{name}: {exc}") from exc
    if label in ("JP2", "JP2L"):
        import io

        from PIL import Image

        try:
            with Image.open(io.BytesIO(data)) as im:
                return im.size[1], im.size[0]
        except Exception as exc:  # Pillow raises many types on corrupt data
            raise ValueError(f"{name}: not a readable JPEG 2000 image ({exc})") from exc
    return None


def read_transaction(source, *, decode: bool = True, name: str | None = None) -> dict:
    """Parse a transaction with ``nistitl`` and check its Type-14 records.

    Parameters
    ----------
    source : path-like or bytes
        The transaction file, or its bytes.
    decode : bool
        Also decode each print (WSQ: NBIS in a child process, about 0.1 s each).
    name : str, optional
        What to call `source` in messages (default: the path, or "transaction").

    Returns
    -------
    dict
        ``{"version", "type1": {tag: value}, "type2": {tag: value} or None,
        "type14": [{tag: value}] (the image as ``bytes`` under 999), "images": [array or
        None], "other_records": [types]}``; values as ``nistitl`` parses them (text; lists of
        subfields; lists of items; IDC an integer).

    Raises
    ------
    ValueError
        Naming the file: not a transaction (``nistitl``'s reason), or a Type-14 record whose
        impression type, position, compression, scale or size is not valid, whose 14.996 hash
        does not match its image, or whose position repeats another's.
    """
    import nistitl

    if isinstance(source, (bytes, bytearray)):
        data, name = bytes(source), name or "transaction"
    else:
        path = Path(source)
        name = name or os.fspath(source)
        if not path.is_file():
            raise ValueError(f"{name}: no such transaction file")
        data = path.read_bytes()
    msg = nistitl.Message()
    try:
        msg.parse(data)
    except (nistitl.NistException, ValueError, IndexError, KeyError, UnicodeError) as exc:
        raise ValueError(f"{name}: not a valid ANSI/NIST-ITL transaction ({exc})") from exc

    def fields_of(record) -> dict:
        return {f.tag: f.value for f in record._fields}

    result: dict = {"version": None, "type1": fields_of(msg[0]), "type2": None, "type14": [],
                    "images": [], "other_records": []}
    result["version"] = result["type1"].get(2)
    positions: dict[int, object] = {}
    for record in list(msg)[1:]:
        if record.type == 2:
            result["type2"] = fields_of(record)
            continue
        if record.type != 14:
            result["other_records"].append(record.type)
            continue
        fields = fields_of(record)
        idc = fields.get(2)
        where = f"{name}: Type-14 record IDC {idc}"
        for tag in (3, 6, 7, 8, 9, 10, 11, 12, 13, 999):
            if tag not in fields:
                raise ValueError(f"{where}: field 14.{tag:03d} is missing")
        impression = _as_int(fields[3], f"{where}: 14.003 IMP")
        if impression not in IMPRESSION_TYPES:
            raise ValueError(f"{where}: 14.003 IMP {impression} is not an impression type "
                             "of ANSI/NIST-ITL 1-2011 Update:2015")
        position = _as_int(fields[13], f"{where}: 14.013 FGP")
        if position not in FINGER_POSITIONS:
            raise ValueError(f"{where}: 14.013 FGP {position} is not a finger position")
        if position in positions:
            raise ValueError(f"{where}: finger position {position} repeats record IDC "
                             f"{positions[position]}")
        positions[position] = idc
        label = fields[11]
        if label not in COMPRESSION_LABELS:
            raise ValueError(f"{where}: 14.011 CGA {label!r} is not a compression label "
                             f"({', '.join(COMPRESSION_LABELS)})")
        if fields[8] != "1" or fields[9] != fields[10] or _as_int(fields[9], where) <= 0:
            raise ValueError(f"{where}: scale {fields[8]!r} {fields[9]!r} x {fields[10]!r}; "
                             "expected SLC 1 (pixels per inch) and equal positive THPS, TVPS")
        if fields[12] != "8":
            raise ValueError(f"{where}: 14.012 BPX {fields[12]!r}; expected 8")
        shape = (_as_int(fields[7], f"{where}: 14.007 VLL"),
                 _as_int(fields[6], f"{where}: 14.006 HLL"))
        image_data = fields[999]
        if 996 in fields and hashlib.sha256(image_data).hexdigest() != fields[996]:
            raise ValueError(f"{where}: the image does not match its 14.996 hash")
        image = None
        stored: tuple[int, ...] | None
        if decode:
            image = _decode(label, image_data, shape, f"{where}: image")
            stored = image.shape
        else:
            stored = _stored_shape(label, image_data, f"{where}: image")
        if stored is not None and tuple(stored) != shape:
            raise ValueError(f"{where}: the image is {stored[1]} x {stored[0]} pixels, the "
                             f"record says {shape[1]} x {shape[0]} (HLL x VLL)")
        result["type14"].append(fields)
        result["images"].append(image)
    return result


def export_transaction(
    job_dirs: Sequence[str | os.PathLike],
    out: str | os.PathLike,
    *,
    positions: Sequence[int] | None = None,
    ppi: int | None = None,
    type2=None,
    **options,
) -> dict:
    """Write one transaction of the prints of `job_dirs` (one person's fingers) to `out`.

    Everything is checked before anything is written: the output path, the positions (one per
    job; a single job without one is the unknown finger, 0), the Type-2 file, each job and its
    print's resolution; the transaction is then built, read back with ``nistitl`` (structure,
    sizes, hashes) and written atomically.

    Parameters
    ----------
    job_dirs : sequence of path-like
        ``process`` / ``batch`` job directories.
    out : path-like
        The transaction file.
    positions : sequence of int, optional
        Finger position of each job, in order.
    ppi : int, optional
        500 or 1000: every print must be at it (default: each print's own, 500 or 1000).
    type2 : path-like or dict, optional
        Type-2 fields (:func:`load_type2`).
    **options
        :func:`build_transaction`'s keywords (``impression``, ``wsq_bitrate``, ``tot``, …).

    Returns
    -------
    dict
        :func:`build_transaction`'s summary, with ``"transaction"`` (the path) and without
        ``fields``.

    Raises
    ------
    ValueError
        Naming the option, file or job and the value given.
    """
    out = check_output_file(out)
    job_dirs = list(job_dirs)
    if not job_dirs:
        raise ValueError("JOB_DIR: expected at least one job directory")
    if positions is None:
        if len(job_dirs) > 1:
            raise ValueError(f"--finger-position: {len(job_dirs)} job directories need a "
                             "finger position each (e.g. --finger-position 1 2 …)")
        positions = [0]
    positions = list(positions)
    if len(positions) != len(job_dirs):
        raise ValueError(f"--finger-position: {len(positions)} position(s) for "
                         f"{len(job_dirs)} job directories; give one per job, in order")
    checked: list[int] = []
    seen: dict[int, str] = {}
    for job, position in zip(job_dirs, positions, strict=True):
        code = check_position(position, "--finger-position")
        if code in seen:
            raise ValueError(f"--finger-position: {code} ({FINGER_POSITIONS[code]}) is given "
                             f"twice (for {seen[code]} and {os.fspath(job)})")
        seen[code] = os.fspath(job)
        checked.append(code)
    if ppi is not None and ppi not in PPI_CHOICES:
        raise ValueError(f"--ppi: expected 500 or 1000, got {ppi}")
    # the options, named as the command's, before any job is read
    low, high = WSQ_BITRATE_RANGE
    bitrate = options.get("wsq_bitrate", WSQ_BITRATE)
    if not (isinstance(bitrate, (int, float)) and low <= bitrate <= high):
        raise ValueError(f"--wsq-bitrate: expected {low:g} to {high:g} bits per pixel, got "
                         f"{bitrate}")
    check_impression(options.get("impression", ROLLED_CONTACTLESS_STATIONARY), "--impression")
    _check_tot(options.get("tot", DEFAULT_TOT), "--tot")
    for key in ("ori", "dai"):
        _text(options.get(key, AGENCY_DEFAULT), f"--{key}")
    _device_items(options.get("device"), "--device")
    fields2 = load_type2(type2) if type2 is not None else None
    fingers = []
    for job, code in zip(job_dirs, checked, strict=True):
        finger = read_job(job)
        if ppi is not None and abs(finger.ppi - ppi) > 0.05:
            raise ValueError(f"--ppi: {os.fspath(job)} holds a {finger.ppi:g} ppi print, not "
                             f"{ppi}; run `nail2nail process … --ppi {ppi}` for it")
        fingers.append((code, finger))
    data, summary = build_transaction(fingers, type2=fields2, **options)
    try:
        read_transaction(data, decode=False, name=os.fspath(out))
    except ValueError as exc:  # what was built must read back: a failure here is a bug
        raise RuntimeError(f"the transaction built does not read back: {exc}") from exc
    with atomic_path(out) as tmp:
        tmp.write_bytes(data)
    summary = {"transaction": os.fspath(out), **{k: v for k, v in summary.items()
                                                 if k != "fields"}}
    return summary
