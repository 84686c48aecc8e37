#!/usr/bin/env python3
"""Every `geodesicd serve` flag is documented: `--help` (which the command
line's parser writes, and which --config's `flags` share) names each flag,
and the pages under docs/ or README.md must name each of them too, so that
a flag added to the parser cannot go undocumented.

Usage: serve_flags_test.py BUILD_BIN_DIR SOURCE_DIR
"""
import glob
import os
import re
import subprocess
import sys


def main():
    bin_dir, src = sys.argv[1], sys.argv[2]
    help_text = subprocess.run([os.path.join(bin_dir, "geodesicd"), "serve", "--help"],
                               capture_output=True, text=True, timeout=60, check=True).stdout
    flags = sorted(set(re.findall(r"^\s+(--[a-z][a-z0-9-]*)", help_text, re.M)) - {"--help"})
    if len(flags) < 20:
        print(f"FAIL: geodesicd serve --help names {len(flags)} flags:\n{help_text}")
        return 1
    pages = [os.path.join(src, "README.md")] + glob.glob(os.path.join(src, "docs", "*.md"))
    text = "\n".join(open(p).read() for p in pages)
    missing = [f for f in flags if not re.search(re.escape(f) + r"(?![a-z0-9-])", text)]
    for flag in missing:
        print(f"FAIL: {flag} is in `geodesicd serve --help` but on no page under docs/")
    print(f"serve flags: {len(flags)}, {len(missing)} undocumented")
    return 1 if missing else 0


if __name__ == "__main__":
    sys.exit(main())
