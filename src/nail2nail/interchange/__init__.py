"""Prints in the form fingerprint systems exchange: ANSI/NIST-ITL transactions (issue 28).

Modules in data order: :mod:`~nail2nail.interchange.positions` (the standard's code tables),
:mod:`~nail2nail.interchange.jobs` (a job directory's print and capture),
:mod:`~nail2nail.interchange.transaction` (build, write and read back a transaction with
``nistitl``). ``nail2nail export-nist`` is the command; ``docs/interchange.md`` the fields.
"""

from nail2nail.interchange.jobs import FingerPrint, read_job
from nail2nail.interchange.positions import (
    CONTACTLESS_IMPRESSIONS,
    FINGER_POSITIONS,
    IMPRESSION_TYPES,
    check_impression,
    check_position,
)
from nail2nail.interchange.transaction import (
    build_transaction,
    export_transaction,
    load_type2,
    read_transaction,
)

__all__ = [
    "CONTACTLESS_IMPRESSIONS",
    "FINGER_POSITIONS",
    "IMPRESSION_TYPES",
    "FingerPrint",
    "build_transaction",
    "check_impression",
    "check_position",
    "export_transaction",
    "load_type2",
    "read_job",
    "read_transaction",
]
