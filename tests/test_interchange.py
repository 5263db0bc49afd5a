"""ANSI/NIST-ITL transactions of prints and WSQ at a chosen bit rate (issue 28).

Transactions are read back two ways: with ``nistitl`` (IDEMIA's maintained library, through
:func:`nail2nail.interchange.read_transaction`) and with :func:`_independent_read`, a reader of
the traditional encoding written here from the standard (ANSI/NIST-ITL 1-2011 Update:2015,
Annex B: records end with FS 0x1C, fields with GS 0x1D, subfields are separated by RS 0x1E and
items by US 0x1F; field ``T.001`` is the record's length in bytes; field 14.999, the image, is
binary and last). No second maintained reader exists on PyPI. The SourceAFIS score check of the
decoded print is a bench (``bench/nist_roundtrip.py``).
"""

from __future__ import annotations

import hashlib
import io
import json
from types import SimpleNamespace

import numpy as np
import pytest
from PIL import Image

from nail2nail.cli import main
from nail2nail.interchange import (
    build_transaction,
    check_impression,
    check_position,
    load_type2,
    read_job,
    read_transaction,
)
from nail2nail.io._json import write_json
from nail2nail.io.prints import (
    WSQ_MIN_SIDE,
    decode_wsq,
    encode_wsq,
    read_print_image,
    write_print_image,
    wsq_shape,
)
from nail2nail.io.rolled import write_rolled_print

FS, GS, RS, US = b"\x1c", b"\x1d", b"\x1e", b"\x1f"


# --- helpers -------------------------------------------------------------------------------
def _finger_image(seed: int, shape=(120, 100)) -> np.ndarray:
    """A synthetic print: curved ridges about 9 px apart (0.46 mm at 500 ppi) on white."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[: shape[0], : shape[1]].astype(float)
    cy, cx = shape[0] * rng.uniform(0.4, 0.6), shape[1] * rng.uniform(0.4, 0.6)
    angle, period = rng.uniform(0, np.pi), rng.uniform(8.0, 10.0) * shape[0] / 120
    r = np.hypot(y - cy, x - cx)
    phase = 2 * np.pi * ((np.cos(angle) * x + np.sin(angle) * y) / period + 0.004 * r ** 1.5)
    inside = ((y - cy) / (0.47 * shape[0])) ** 2 + ((x - cx) / (0.45 * shape[1])) ** 2 < 1
    return np.where(inside, np.rint(128 + 100 * np.cos(phase)), 255).astype(np.uint8)


def _job(root, name: str, *, seed: int, ppi: float = 500.0, clarity=0.91, shape=(120, 100),
         fmt="nail2nail-rolled-print"):
    """A job directory as `process` writes it, reduced to what export-nist reads."""
    job = root / name
    (job / "print").mkdir(parents=True)
    image = _finger_image(seed, shape)
    write_print_image(job / "print" / "print.png", image, ppi=ppi)
    write_json(job / "print" / "print.json", {
        "format": fmt, "version": 1, "ppi": ppi, "shape": list(shape), "method": "rolled",
        "cameras": ["cam0", "cam1", "cam2"], "quality": {"clarity_median": clarity},
        "files": {"print": "print.png"}})
    capture = root / f"{name}-capture"
    capture.mkdir()
    write_json(capture / "capture.json", {"format": "nail2nail-capture", "version": 1,
                                          "created_by": "nail2nail simulate"})
    write_json(job / "process.json", {"capture": str(capture)})
    return job, image


def _independent_read(data: bytes) -> dict:
    """Records of a traditional-encoding transaction: ``[(type, {tag: value})]``, the image of
    a Type-14 under 999 as bytes; a value is text, a list of subfields, a subfield with several
    items a list. Written from the standard, sharing nothing with nistitl."""

    def value_of(raw: bytes):
        subfields = []
        for sub in raw.split(RS):
            items = [i.decode("ascii") for i in sub.split(US)]
            subfields.append(items[0] if len(items) == 1 else items)
        return subfields[0] if len(subfields) == 1 and isinstance(subfields[0], str) else (
            subfields)

    records, offset = [], 0
    while offset < len(data):
        head = data[offset: offset + 20]
        rtype = int(head[: head.index(b".")])
        length = int(head[head.index(b":") + 1: head.index(GS)])
        record = data[offset: offset + length]
        assert record[-1:] == FS, f"record {rtype} at {offset} does not end with FS"
        body, image = record[:-1], None
        tag999 = f"{GS.decode()}{rtype}.999:".encode()
        if rtype == 14 and tag999 in body:  # binary in image records; text in Type-2
            body, image = body.split(tag999, 1)
        fields = {}
        for field in body.split(GS):
            tag, _, raw = field.partition(b":")
            record_type, number = (int(v) for v in tag.split(b"."))
            assert record_type == rtype
            fields[number] = value_of(raw)
        if image is not None:
            fields[999] = image
        records.append((rtype, fields))
        offset += length
    assert offset == len(data)
    cnt = records[0][1][3]
    assert int(cnt[0][1]) == len(records) - 1
    assert [(int(t), int(i)) for t, i in cnt[1:]] == [
        (t, int(f[2])) for t, f in records[1:]]
    return {"records": records}


def _one_error_line(capsys, *needles):
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("nail2nail export-nist: error: "), err
    for needle in needles:
        assert needle in err[0], (needle, err[0])
    return err[0]


# --- WSQ at a chosen bit rate ----------------------------------------------------------------
def test_wsq_default_rate_matches_the_plugin_and_rate_lowers_size():
    image = _finger_image(3, (160, 140))
    buffer = io.BytesIO()
    import wsq  # noqa: F401  (the Pillow plugin: the encoder at its fixed 0.75)

    Image.fromarray(image).save(buffer, format="WSQ")
    assert encode_wsq(image) == buffer.getvalue()  # same NBIS encoder, same bytes at 0.75
    sizes = [len(encode_wsq(image, bitrate=r)) for r in (0.3, 0.75, 2.0)]
    assert sizes[0] < sizes[1] < sizes[2]
    data = encode_wsq(image, bitrate=0.3)
    assert wsq_shape(data) == image.shape
    back = decode_wsq(data, name="x.wsq")
    assert back.shape == image.shape and np.sqrt(np.mean((back - image.astype(float)) ** 2)) < 25
    assert b"WSQ_BITRATE 0.300000" in data  # the NIST_COM comment records the rate asked


@pytest.mark.parametrize("kwargs, error, message", [
    ({"bitrate": 5.0}, ValueError, "bitrate: expected 0.1..4 bits per pixel, got 5.0"),
    ({"bitrate": 0.05}, ValueError, "got 0.05"),
    ({"bitrate": "0.75"}, TypeError, "bitrate: expected a number"),
])
def test_wsq_bad_rate(kwargs, error, message):
    with pytest.raises(error, match=message):
        encode_wsq(_finger_image(1, (80, 80)), **kwargs)


def test_wsq_too_small_and_write_names_file(tmp_path):
    small = _finger_image(1, (WSQ_MIN_SIDE - 1, 80))
    with pytest.raises(ValueError, match=rf"at least {WSQ_MIN_SIDE} px on each side, got 63 x 80"):
        encode_wsq(small)
    with pytest.raises(ValueError, match=r"p\.wsq: image: WSQ needs at least 64 px"):
        write_print_image(tmp_path / "p.wsq", small)
    assert list(tmp_path.iterdir()) == []
    write_print_image(tmp_path / "q.wsq", _finger_image(1, (80, 90)), bitrate=1.5)
    back, ppi = read_print_image(tmp_path / "q.wsq")
    assert back.shape == (80, 90) and ppi == 500.0


def test_print_json_records_wsq_rate_and_ratio(tmp_path):
    image = _finger_image(5, (120, 100))
    rolled = SimpleNamespace(
        ppi=500.0, image=image, binary=image, mask=np.ones(image.shape, bool),
        share=np.ones((1, *image.shape), np.float32),
        quality={"grid": np.ones((2, 2)), "step_px": 32, "block_px": 64},
        metadata=lambda: {"format": "nail2nail-rolled-print", "ppi": 500.0})
    meta = write_rolled_print(tmp_path / "print", rolled, wsq_bitrate=0.5)
    size = (tmp_path / "print" / "print.wsq").stat().st_size
    on_disk = json.loads((tmp_path / "print" / "print.json").read_text())
    assert on_disk["wsq"] == meta["wsq"] == {
        "bitrate_bpp": 0.5, "achieved_bpp": round(8 * size / image.size, 4),
        "compression_ratio": round(image.size / size, 2), "bytes": size}
    assert on_disk["wsq_compression_ratio"] == round(image.size / size, 2)


# --- the tables --------------------------------------------------------------------------------
def test_tables():
    assert [check_position(p) for p in (0, 1, 10, 16, "17")] == [0, 1, 10, 16, 17]
    with pytest.raises(ValueError, match=r"where: 13 \(plain right four fingers\) is not"):
        check_position(13, "where")
    with pytest.raises(ValueError, match="where: 23 is not a finger position"):
        check_position(23, "where")
    with pytest.raises(TypeError, match="expected an integer code"):
        check_position(True)
    assert check_impression(41) == 41
    with pytest.raises(ValueError, match=r"1 \(rolled contact\) is not a contactless"):
        check_impression(1)


# --- round trips ---------------------------------------------------------------------------
def test_round_trip_every_field_and_image(tmp_path):
    job_a, image_a = _job(tmp_path, "a", seed=1, clarity=0.874)
    job_b, image_b = _job(tmp_path, "b", seed=2, ppi=1000.0, shape=(200, 170), clarity=None)
    type2 = load_type2({"2.018": "DOE, JOHN", "2.020": ["FIRST", "SECOND"],
                        "2.084": [["1", "2", "3"], ["4"]], "2.999": ["ONLY"]})
    assert type2 == {18: "DOE, JOHN", 20: ["FIRST", "SECOND"], 84: [["1", "2", "3"], "4"],
                     999: "ONLY"}
    fingers = [(7, read_job(job_a)), (2, read_job(job_b))]
    data, summary = build_transaction(
        fingers, type2=type2, impression=41, wsq_bitrate=0.6, tot="CAR", ori="WVFBI0000",
        dai="XYZ123", tcn="TCN-1", device=("Acme", "N2N 3", "SN 42"), when=1_700_000_000)
    written = summary["fields"]
    path = tmp_path / "t.an2"
    path.write_bytes(data)

    # nistitl
    back = read_transaction(path)
    assert back["version"] == "0502"
    assert {k: back["type1"][k] for k in written["type1"]} == written["type1"]
    assert {k: v for k, v in back["type2"].items() if k != 1} == written["type2"]
    assert [{k: v for k, v in r.items() if k not in (1, 999)} for r in back["type14"]] == (
        written["type14"])
    # the independent reader
    records = _independent_read(data)["records"]
    assert [t for t, _ in records] == [1, 2, 14, 14]
    assert {k: records[0][1][k] for k in written["type1"]} == written["type1"]
    assert {k: v for k, v in records[1][1].items() if k != 1} == {
        k: (str(v) if k == 2 else v) for k, v in written["type2"].items()}
    for (_, fields), expected, record in zip(records[2:], written["type14"], back["type14"],
                                             strict=True):
        assert {k: v for k, v in fields.items() if k not in (1, 999)} == {
            k: (str(v) if k == 2 else v) for k, v in expected.items()}
        assert fields[999] == record[999]  # the same image bytes for both readers
        assert hashlib.sha256(fields[999]).hexdigest() == expected[996]

    # what was asked: position 2 is the 1000 ppi print (JPEG 2000), 7 the 500 ppi one (WSQ)
    by_position = {int(r[13]): (r, img) for r, img in zip(back["type14"], back["images"],
                                                          strict=True)}
    wsq_record, wsq_image = by_position[7]
    jp2_record, jp2_image = by_position[2]
    assert (wsq_record[3], wsq_record[11], wsq_record[9], wsq_record[6], wsq_record[7]) == (
        "41", "WSQ20", "500", "100", "120")
    assert (jp2_record[11], jp2_record[9], jp2_record[10]) == ("JP2", "1000", "1000")
    assert wsq_record[24] == [["7", "87", "0000", "1"]] and 24 not in jp2_record
    assert wsq_record[904] == [["Acme", "N2N 3", "SN 42"]] and wsq_record[4] == "WVFBI0000"
    assert "nail2nail simulate" in wsq_record[20]
    # images: the record holds the encoder's bytes; decoded, the codec's loss only
    assert wsq_record[999] == encode_wsq(image_a, bitrate=0.6)
    rms_wsq = np.sqrt(np.mean((wsq_image.astype(float) - image_a) ** 2))
    rms_jp2 = np.sqrt(np.mean((jp2_image.astype(float) - image_b) ** 2))
    assert wsq_image.shape == image_a.shape and jp2_image.shape == image_b.shape
    assert 0 < rms_wsq < 15 and 0 < rms_jp2 < 15, (rms_wsq, rms_jp2)
    ratios = {p["position"]: p["compression_ratio"] for p in summary["prints"]}
    assert ratios[7] == round(image_a.size / len(wsq_record[999]), 2)


def test_ten_finger_transaction_from_the_command(tmp_path, capsys):
    jobs = [_job(tmp_path, f"finger{i}", seed=10 + i, shape=(96, 80))[0] for i in range(10)]
    out = tmp_path / "out" / "person.an2"
    args = ["export-nist", *map(str, jobs), "-o", str(out), "--finger-position",
            *[str(p) for p in range(10, 0, -1)], "--json", "--ori", "TESTORI01"]
    assert main(args) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["transaction"] == str(out) and summary["bytes"] == out.stat().st_size
    assert [p["position"] for p in summary["prints"]] == list(range(1, 11))
    assert [p["source"] for p in summary["prints"]] == [str(j) for j in reversed(jobs)]
    data = out.read_bytes()
    back = read_transaction(out)  # nistitl, and the records' checks
    assert [int(r[13]) for r in back["type14"]] == list(range(1, 11))
    assert {r[3] for r in back["type14"]} == {"25"} and back["type2"] is None
    assert all(img.shape == (96, 80) for img in back["images"])
    records = _independent_read(data)["records"]
    assert [t for t, _ in records] == [1] + [14] * 10
    assert [int(f[13]) for _, f in records[1:]] == list(range(1, 11))
    assert [f[999] for _, f in records[1:]] == [r[999] for r in back["type14"]]
    assert records[0][1][2] == "0502" and records[0][1][8] == "TESTORI01"
    assert sorted(p.name for p in out.parent.iterdir()) == ["person.an2"]


# --- malformed inputs: exit 2, one line, nothing written ------------------------------------
def _bad_cases(root):
    job_a, _ = _job(root, "a", seed=1)
    job_b, _ = _job(root, "b", seed=2)
    job_750, _ = _job(root, "c750", seed=3, ppi=750.0, shape=(180, 150))
    other, _ = _job(root, "other", seed=4, fmt="nail2nail-scan")
    (root / "empty").mkdir()
    (root / "t2_key.json").write_text('{"18": "x"}')
    (root / "t2_idc.json").write_text('{"2.002": "1"}')
    (root / "t2_value.json").write_text('{"2.018": {"a": 1}}')
    (root / "t2_text.json").write_text('{"2.018": "caf\\u00e9"}')
    (root / "t2_bad.json").write_text('{"2.018": ')
    a, b = str(job_a), str(job_b)
    return {
        "missing job": ([a, str(root / "nope"), "--finger-position", "1", "2"],
                        [str(root / "nope"), "no such job directory"]),
        "not a job": ([str(root / "empty")], ["empty", "no print/print.json"]),
        "print.json of another format": ([str(other)], ["print.json", "'nail2nail-scan'"]),
        "duplicate position": ([a, b, "--finger-position", "3", "3"],
                               ["--finger-position", "3 (right middle finger) is given twice"]),
        "position outside the table": ([a, "--finger-position", "23"],
                                       ["--finger-position", "23 is not a finger position"]),
        "several fingers' position": ([a, "--finger-position", "14"],
                                      ["--finger-position", "14 (plain left four fingers)"]),
        "negative position": ([a, "--finger-position", "-1"], ["--finger-position", "-1"]),
        "positions for jobs": ([a, b, "--finger-position", "1"],
                               ["--finger-position", "1 position(s) for 2 job directories"]),
        "no positions": ([a, b], ["--finger-position", "2 job directories need"]),
        "ppi mismatch": ([a, "--ppi", "1000"], ["--ppi", "500 ppi print, not 1000"]),
        "print at 750 ppi": ([str(job_750)], ["c750", "750 ppi"]),
        "bitrate": ([a, "--wsq-bitrate", "6"], ["--wsq-bitrate", "got 6"]),
        "tot": ([a, "--tot", "CAR 2"], ["--tot", "'CAR 2'"]),
        "ori": ([a, "--ori", "caf\u00e9"], ["--ori", "'caf\u00e9'"]),
        "device": ([a, "--device", "Acme/X"], ["--device", "'Acme/X'"]),
        "type2 key": ([a, "--type2", str(root / "t2_key.json")], ["t2_key.json", "'18'"]),
        "type2 idc": ([a, "--type2", str(root / "t2_idc.json")], ["t2_idc.json", "'2.002'"]),
        "type2 value": ([a, "--type2", str(root / "t2_value.json")],
                        ["t2_value.json: 2.018", "{'a': 1}"]),
        "type2 text": ([a, "--type2", str(root / "t2_text.json")],
                       ["t2_text.json: 2.018", "printable ASCII"]),
        "type2 json": ([a, "--type2", str(root / "t2_bad.json")],
                       ["t2_bad.json", "not valid JSON"]),
        "type2 missing": ([a, "--type2", str(root / "none.json")], ["none.json"]),
    }


def test_malformed_inputs_refused(tmp_path, capsys):
    cases = _bad_cases(tmp_path / "in")
    for name, (args, needles) in cases.items():
        out = tmp_path / "out" / f"{name}.an2"
        code = main(["export-nist", *args, "-o", str(out)])
        assert code == 2, name
        _one_error_line(capsys, *needles)
        assert not (tmp_path / "out").exists(), name


def test_output_refused_and_argparse_codes(tmp_path, capsys):
    job, _ = _job(tmp_path, "a", seed=1)
    (tmp_path / "dir.an2").mkdir()
    assert main(["export-nist", str(job), "-o", str(tmp_path / "dir.an2")]) == 2
    _one_error_line(capsys, "dir.an2", "is a directory")
    for option, value in (("--ppi", "600"), ("--impression", "1"), ("--wsq-bitrate", "x")):
        with pytest.raises(SystemExit) as stop:  # argparse's usage errors
            main(["export-nist", str(job), "-o", str(tmp_path / "x.an2"), option, value])
        assert stop.value.code == 2
        assert f"argument {option}: invalid" in capsys.readouterr().err
    assert not (tmp_path / "x.an2").exists()


# --- reading refuses what is not a valid transaction ----------------------------------------
def test_read_refuses_broken_transactions(tmp_path):
    job, _ = _job(tmp_path, "a", seed=1, shape=(80, 80))
    data, _ = build_transaction([(10, read_job(job))], tcn="T", when=0)  # edits keep lengths
    cases = {
        "cut.an2": (data[:-10], "cut.an2: not a valid ANSI/NIST-ITL transaction"),
        "hash.an2": (data[:-5] + bytes([data[-5] ^ 0xFF]) + data[-4:],
                     "does not match its 14.996 hash"),
        "position.an2": (data.replace(b"\x1d14.013:10\x1d", b"\x1d14.013:99\x1d"),
                         "14.013 FGP 99 is not a finger position"),
        "impression.an2": (data.replace(b"\x1d14.003:25\x1d", b"\x1d14.003:99\x1d"),
                           "14.003 IMP 99 is not an impression type"),
        "size.an2": (data.replace(b"\x1d14.006:80\x1d", b"\x1d14.006:81\x1d"),
                     "the image is 80 x 80 pixels, the record says 81 x 80"),
    }
    for name, (content, message) in cases.items():
        assert content != data, name
        (tmp_path / name).write_bytes(content)
        with pytest.raises(ValueError, match=message):
            read_transaction(tmp_path / name)
    with pytest.raises(ValueError, match="no such transaction file"):
        read_transaction(tmp_path / "missing.an2")
    # two records of one finger, made with nistitl directly
    import nistitl

    msg = nistitl.Message()
    msg.parse(data)
    twin = nistitl.Message()
    twin.parse(data)
    second = twin[1]
    second.IDC = 2
    msg += second
    with pytest.raises(ValueError, match="finger position 10 repeats record IDC 1"):
        read_transaction(msg.NIST, decode=False, name="twins.an2")


# --- batch: one transaction per subject ---------------------------------------------------------
def test_subject_table_and_transactions(tmp_path, capsys):
    from nail2nail.interchange.subjects import export_subjects, read_subject_table

    jobs = {name: _job(tmp_path / "out", name, seed=20 + i, shape=(80, 72))[0]
            for i, name in enumerate(["c1", "c2", "c3", "c4"])}
    captures = [tmp_path / "captures" / name for name in jobs]
    table = tmp_path / "subjects.csv"
    table.write_text("capture,subject,finger_position\nc1,alice,2\nc2,alice,7\nc3,bob,1\n"
                     "c4,carol,6\n")
    subjects = read_subject_table(table, captures)
    assert subjects == {"alice": [("c1", 2), ("c2", 7)], "bob": [("c3", 1)],
                        "carol": [("c4", 6)]}
    rows = [{"capture": name, "status": "failed" if name == "c4" else "done", "out": str(job)}
            for name, job in jobs.items()]
    written = export_subjects(subjects, rows, tmp_path / "out")
    assert written == [str(tmp_path / "out" / "transactions" / f"{s}.an2")
                       for s in ("alice", "bob")]
    assert "subject carol: capture c4 failed; no transaction written" in capsys.readouterr().err
    alice = read_transaction(written[0], decode=False)
    assert [int(r[13]) for r in alice["type14"]] == [2, 7]
    assert [int(f[13]) for t, f in _independent_read(
        (tmp_path / "out" / "transactions" / "alice.an2").read_bytes())["records"][1:]] == [2, 7]

    bad = {
        "capture,subject\nc1,alice\n": "no column 'finger_position'",
        "capture,subject,finger_position\nc9,alice,2\n": "line 2: capture 'c9' is not one",
        "capture,subject,finger_position\nc1,alice,2\nc1,bob,3\n": "line 3: capture 'c1' is "
                                                                    "listed twice",
        "capture,subject,finger_position\nc1,alice,2\nc2,alice,2\n": "line 3: subject 'alice' "
                                                                      "has finger position 2",
        "capture,subject,finger_position\nc1,a/b,2\n": "line 2: subject: 'a/b' is not a plain",
        "capture,subject,finger_position\nc1,alice,13\n": "line 2: finger_position: 13",
        "capture,subject,finger_position\nc1,alice,x\n": "finger_position: expected an integer",
        "capture,subject,finger_position\n": "no rows",
    }
    for text, message in bad.items():
        table.write_text(text)
        with pytest.raises(ValueError, match=message):
            read_subject_table(table, captures)
    with pytest.raises(ValueError, match="a capture is named 'transactions'"):
        read_subject_table(table, [tmp_path / "transactions"])
