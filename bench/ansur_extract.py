"""Writes oracles/bodies/data/ansur2.csv.gz from the public ANSUR II files (see that folder's README).

Run: ``.venv/bin/python bench/ansur_extract.py [--source ../shared/data/ansur2]``. Prints the uncompressed CSV's
sha256 as a JSON line; the README beside the data quotes it.

``--check``: writes nothing; extracts the public files again and compares every row and column with the carried file,
exit 1 naming the first difference (CI runs it, ``.ci/run``: the tests themselves use only the carried file).
"""

from __future__ import annotations

import argparse
import csv
import gzip
import hashlib
import io
import json
import sys
from pathlib import Path

from oracles.bodies.ansur import COLUMNS, DATA

FILES = (("male", "ANSUR_II_MALE_Public.csv", "subjectid"), ("female", "ANSUR_II_FEMALE_Public.csv", "SubjectId"))


def extract(source: Path) -> bytes:
    """The carried CSV's bytes, uncompressed, from the two public files in ``source``."""
    buf = io.StringIO()
    out = csv.writer(buf, lineterminator="\n")
    out.writerow(["sex", "subject", *COLUMNS])
    for sex, name, id_column in FILES:
        path = source / name
        if not path.exists():
            sys.exit(f"{path}: not found (the public ANSUR II files, Penn State OPENLAB's 'ANSUR II working "
                     "databases'; see oracles/bodies/data/README.md)")
        with open(path, encoding="latin-1", newline="") as fh:
            for row in csv.DictReader(fh):
                out.writerow([sex, row[id_column], *(row[c] for c in COLUMNS)])
    return buf.getvalue().encode()


def check(data: bytes) -> None:
    """Exit 1 at the first line where the carried file differs from ``data``."""
    with gzip.open(DATA, "rb") as gz:
        carried = gz.read()
    ours, theirs = carried.decode().splitlines(), data.decode().splitlines()
    for line, (a, b) in enumerate(zip(ours, theirs, strict=False), start=1):
        if a != b:
            sys.exit(f"{DATA}: line {line} differs from the public files: {a!r}, public {b!r}")
    if len(ours) != len(theirs):
        sys.exit(f"{DATA}: {len(ours) - 1} rows, the public files {len(theirs) - 1}")
    print(json.dumps({"file": str(DATA), "rows": len(ours) - 1, "same_as_public": True,
                      "sha256": hashlib.sha256(carried).hexdigest()}))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--source", default="../shared/data/ansur2", help="the folder of the two public CSV files")
    parser.add_argument("--check", action="store_true", help="compare the carried file with the public files; "
                        "write nothing")
    args = parser.parse_args()
    data = extract(Path(args.source))
    if args.check:
        check(data)
        return
    with open(DATA, "wb") as fh, gzip.GzipFile(filename="", mode="wb", fileobj=fh, mtime=0, compresslevel=9) as gz:
        gz.write(data)  # mtime 0: the same files give the same bytes
    print(json.dumps({"file": str(DATA), "rows": data.count(b"\n") - 1, "sha256": hashlib.sha256(data).hexdigest()}))


if __name__ == "__main__":
    main()
