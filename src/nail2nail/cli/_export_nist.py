"""``nail2nail export-nist``: one ANSI/NIST-ITL transaction of a person's prints (issue 28).

Thin command layer over :func:`nail2nail.interchange.export_transaction`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from nail2nail.interchange.positions import ROLLED_CONTACTLESS_STATIONARY
from nail2nail.interchange.transaction import (
    AGENCY_DEFAULT,
    DEFAULT_TOT,
    PPI_CHOICES,
    TEXT_MAX,
    TOT_MAX,
    export_transaction,
)
from nail2nail.io._json import dumps_json
from nail2nail.io.prints import WSQ_BITRATE, WSQ_BITRATE_RANGE

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:
    low, high = WSQ_BITRATE_RANGE
    p = sub.add_parser(
        "export-nist",
        help="one ANSI/NIST-ITL transaction (Type-1, Type-2, a Type-14 per finger) of prints",
        description="Write the prints of one or more job directories of `process` or `batch` "
        "(one person's fingers) as one ANSI/NIST-ITL 1-2011 Update:2015 transaction, "
        "traditional encoding: a Type-1 record, an optional Type-2 record of your fields and a "
        "Type-14 record per finger with a contactless impression type, its finger position, "
        "resolution, compression (WSQ at 500 ppi, JPEG 2000 at 1000 ppi), quality and the "
        "capture's description. The transaction is read back before it is written. Fields "
        "and sources: docs/interchange.md.",
    )
    p.add_argument("jobs", nargs="+", type=Path, metavar="JOB_DIR",
                   help="job directory of `process` or `batch` (print/print.json)")
    p.add_argument("-o", "--out", type=Path, required=True, metavar="TRANSACTION",
                   help="transaction file to write (e.g. person.an2)")
    p.add_argument("--finger-position", type=int, nargs="+", default=None, metavar="N",
                   help="finger position of each job, in order (ANSI/NIST-ITL: 1-5 right "
                   "thumb to little finger, 6-10 left, 0 unknown, 16/17 extra digits); "
                   "required for several jobs, 0 for one by default; no position twice")
    p.add_argument("--ppi", type=int, choices=PPI_CHOICES, default=None,
                   help="resolution every print must have: 500 (WSQ) or 1000 (JPEG 2000); "
                   "default: each print's own, which must be one of them")
    p.add_argument("--type2", type=Path, default=None, metavar="FIELDS.json",
                   help='Type-2 fields of your application profile: {"2.NNN": value}, a value '
                   "being text, a list of subfields or a list of lists of items (ASCII)")
    p.add_argument("--impression", type=int, default=ROLLED_CONTACTLESS_STATIONARY,
                   choices=(24, 25, 41, 42),
                   help="14.003 impression type: 24 plain or 25 rolled contactless, stationary "
                   "subject; 41 rolled or 42 plain contactless, moving subject (default 25)")
    p.add_argument("--wsq-bitrate", type=float, default=WSQ_BITRATE, metavar="BPP",
                   help=f"WSQ bit rate of 500 ppi prints, {low:g} to {high:g} bits per pixel "
                   f"(default {WSQ_BITRATE:g}, the FBI's: 12.2:1 on the demo print; 0.6 gives "
                   "14.7:1)")
    p.add_argument("--tot", default=DEFAULT_TOT,
                   help=f"1.004 transaction type, 1 to {TOT_MAX} letters (default "
                   f"{DEFAULT_TOT}, nail2nail's own; give your profile's)")
    p.add_argument("--ori", default=AGENCY_DEFAULT,
                   help=f"1.008 originating agency, also 14.004 source agency (printable ASCII, "
                   f"at most {TEXT_MAX} characters; default {AGENCY_DEFAULT})")
    p.add_argument("--dai", default=AGENCY_DEFAULT,
                   help=f"1.007 destination agency (default {AGENCY_DEFAULT})")
    p.add_argument("--device", default=None, metavar="MAKE/MODEL/SERIAL",
                   help="14.904 make, model and serial number of the scanner, '/'-separated "
                   "(default: none written; field 14.020 describes the capture)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(func=run)


def _device(text: str | None):
    if text is None:
        return None
    parts = text.split("/")
    if len(parts) != 3 or not all(parts):
        raise ValueError(f"--device: expected MAKE/MODEL/SERIAL (three non-empty parts), got "
                         f"{text!r}")
    return parts


def run(args: argparse.Namespace) -> int:

    summary = export_transaction(
        args.jobs, args.out, positions=args.finger_position, ppi=args.ppi, type2=args.type2,
        impression=args.impression, wsq_bitrate=args.wsq_bitrate, tot=args.tot, ori=args.ori,
        dai=args.dai, device=_device(args.device))
    if args.json:
        print(dumps_json(summary))
        return 0
    for p in summary["prints"]:
        print(f"{p['idc']:>2} {p['position']:>2} {p['position_name']:<20} {p['compression']:<6}"
              f"{p['ppi']} ppi {p['shape'][1]} x {p['shape'][0]}  {p['compression_ratio']:.1f}:1"
              f"  quality {p['quality'] if p['quality'] is not None else '-'}")
    print(f"wrote {summary['transaction']} ({summary['bytes']} bytes, version "
          f"{summary['version']}, TOT {summary['tot']}, TCN {summary['tcn']})")
    return 0
