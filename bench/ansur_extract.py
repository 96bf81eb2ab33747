"""Writes oracles/bodies/data/ansur2.csv.gz from the public ANSUR II files (see that folder's README).

Run: ``.venv/bin/python bench/ansur_extract.py [--source ../shared/data/ansur2]``. Prints the uncompressed CSV's
sha256 as a JSON line; the README beside the data quotes it.
"""

from __future__ import annotations

import argparse
import csv
import gzip
import hashlib
import io
import json
from pathlib import Path

from oracles.bodies.ansur import COLUMNS, DATA

FILES = (("male", "ANSUR_II_MALE_Public.csv", "subjectid"), ("female", "ANSUR_II_FEMALE_Public.csv", "SubjectId"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--source", default="../shared/data/ansur2", help="the folder of the two public CSV files")
    args = parser.parse_args()
    buf = io.StringIO()
    out = csv.writer(buf, lineterminator="\n")
    out.writerow(["sex", "subject", *COLUMNS])
    for sex, name, id_column in FILES:
        with open(Path(args.source) / name, encoding="latin-1", newline="") as fh:
            for row in csv.DictReader(fh):
                out.writerow([sex, row[id_column], *(row[c] for c in COLUMNS)])
    data = buf.getvalue().encode()
    with open(DATA, "wb") as fh, gzip.GzipFile(filename="", mode="wb", fileobj=fh, mtime=0, compresslevel=9) as gz:
        gz.write(data)  # mtime 0: the same files give the same bytes
    print(json.dumps({"file": str(DATA), "rows": data.count(b"\n") - 1, "sha256": hashlib.sha256(data).hexdigest()}))


if __name__ == "__main__":
    main()
