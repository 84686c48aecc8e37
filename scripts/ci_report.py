#!/usr/bin/env python3
"""Writes measured times into docs/ci.md, each table between its own markers:
CI's lanes (build/ci-lanes.tsv, written by .ci/run) and the quick start's
steps (build/quickstart-times.tsv, written by scripts/quickstart.sh). The rest
of the file is left as it is.

Usage: scripts/ci_report.py (--lanes TSV | --quickstart TSV) --note TEXT
  --note says how the numbers were taken (machine, fresh clone, cold or warm ccache).
"""
import argparse
import csv
import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
QUICKSTART_STEPS = {
    "built": "the daemon and the CLI built",
    "first_answer": "first answer (a distance and its path)",
    "answered": "every answer of the sample run",
    "installed": "binaries installed",
}


def read_rows(path):
    with open(path, newline="") as f:
        rows = [row for row in csv.reader(f, delimiter="\t") if row]
    if not rows:
        sys.exit(f"ci_report: {path} has no rows")
    return rows


def lanes_table(rows):
    if rows[0] != ["lane", "seconds", "result"]:
        sys.exit(f"ci_report: not a lane table (header {rows[0]})")
    out = ["| lane | seconds | minutes | result |", "|---|---:|---:|---|"]
    for name, seconds, result in rows[1:]:
        out.append(f"| {name} | {seconds} | {int(seconds) / 60:.1f} | {result} |")
    return out


def quickstart_table(rows):
    out = ["| quick start, from its start | seconds |", "|---|---:|"]
    out += [f"| {QUICKSTART_STEPS.get(step, step)} | {seconds} |" for step, seconds in rows]
    return out


def replace_section(text, name, body):
    begin, end = f"<!-- ci_report.py {name}: begin -->", f"<!-- ci_report.py {name}: end -->"
    if begin not in text or end not in text:
        sys.exit(f"ci_report: docs/ci.md has no {begin} ... {end} section")
    head, rest = text.split(begin, 1)
    return head + begin + "\n" + body + "\n" + end + rest.split(end, 1)[1]


def main():
    parser = argparse.ArgumentParser()
    kind = parser.add_mutually_exclusive_group(required=True)
    kind.add_argument("--lanes", help="build/ci-lanes.tsv from .ci/run")
    kind.add_argument("--quickstart", help="build/quickstart-times.tsv from scripts/quickstart.sh")
    parser.add_argument("--note", required=True, help="how and where the numbers were taken")
    parser.add_argument("--doc", default=os.path.join(ROOT, "docs", "ci.md"))
    args = parser.parse_args()
    if args.lanes:
        name, table = "lanes", lanes_table(read_rows(args.lanes))
    else:
        name, table = "quickstart", quickstart_table(read_rows(args.quickstart))
    body = "\n".join([args.note, ""] + table)
    with open(args.doc) as f:
        text = f.read()
    with open(args.doc, "w") as f:
        f.write(replace_section(text, name, body))


if __name__ == "__main__":
    main()
