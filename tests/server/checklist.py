"""The report of the Python tests that run as scripts: a line per check
("ok   name" or "FAIL name: detail"), then the counts, and the exit status."""
import sys


class Checklist:
    def __init__(self):
        self.passes = 0
        self.failures = 0

    def __call__(self, name, ok, detail=""):
        print(("ok   " if ok else "FAIL ") + name + ("" if ok else f": {detail}"), flush=True)
        self.passes += bool(ok)
        self.failures += not ok
        return bool(ok)

    def finish(self):
        """Prints the counts and exits: 1 if any check failed."""
        print(f"{self.passes} passed, {self.failures} failed")
        sys.exit(1 if self.failures else 0)
