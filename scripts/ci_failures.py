#!/usr/bin/python3
"""The end of each failed test's output, from CTest's logs in the given build
directories, for .ci/run to print last: a CI log is often read from its end,
where ctest's own --output-on-failure text is long gone.

    ci_failures.py [--lines N] BUILD_DIR...
"""
import argparse
import os
import re

# Lines that say why a test failed, in our shell tests (FAIL), GoogleTest,
# Python's unittest and ctest's own verdicts; repeated last, since the tails
# above can be longer than what a CI log keeps of its end.
VERDICT = re.compile(r"^FAIL\b|^\[  FAILED  \]|Failure$|^Expected|^  Actual|^Value of|^Which is|"
                     r"Error\b|^Traceback|Timeout|did not")


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
    parser.add_argument("--verdicts", type=int, default=6,
                        help="lines saying why, kept of each failed test")
    args = parser.parse_args()
    verdicts = []
    for build_dir in args.build_dirs:
        for name, output in failed_outputs(build_dir).items():
            lines = output.splitlines()
            print(f"=== failed in {build_dir}: {name} (its last {args.lines} lines of "
                  f"{len(lines)})")
            print("\n".join(lines[-args.lines:]))
            why = [line for line in lines if VERDICT.search(line)][:args.verdicts]
            verdicts.append(f"{build_dir}: {name}")
            verdicts.extend("  " + line[:200] for line in why)
    if verdicts:
        print("=== why they failed")
        print("\n".join(verdicts))


if __name__ == "__main__":
    main()
