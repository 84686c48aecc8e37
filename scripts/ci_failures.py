#!/usr/bin/python3
"""The end of each failed test's output, from CTest's logs in the given build
directories, for .ci/run to print last: a CI log is often read from its end,
where ctest's own --output-on-failure text is long gone.

    ci_failures.py [--lines N] BUILD_DIR...
"""
import argparse
import os
import re


def failed_outputs(build_dir):
    """Each failed test's output in the last run (LastTest.log is written anew
    by every run, unlike LastTestsFailed.log, which a passing run leaves)."""
    path = os.path.join(build_dir, "Testing", "Temporary", "LastTest.log")
    if not os.path.exists(path):
        return {}
    with open(path, errors="replace") as f:
        log = f.read()
    found = {}
    for m in re.finditer(r"^\d+/\d+ Test: (.+?)\n.*?^Output:\n-+\n(.*?)^<end of output>\n"
                         r"(.*?)end time:", log, re.M | re.S):
        if "Test Failed" in m.group(3):
            found[m.group(1)] = m.group(2)
    return found


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--lines", type=int, default=60, help="lines of each output kept")
    parser.add_argument("build_dirs", nargs="+")
    args = parser.parse_args()
    for build_dir in args.build_dirs:
        for name, output in failed_outputs(build_dir).items():
            lines = output.splitlines()
            print(f"=== failed in {build_dir}: {name} (its last {args.lines} lines of "
                  f"{len(lines)})")
            print("\n".join(lines[-args.lines:]))


if __name__ == "__main__":
    main()
