"""The peak of a running process's resident anonymous memory (RssAnon),
which getrusage's peak does not tell apart from mapped file pages: the
benchmarks' builds keep their edge arrays in mapped graph files."""
import time


def anonymous_bytes(pid):
    """RssAnon of pid and its descendants (0 for those already gone)."""
    total = 0
    try:
        with open(f"/proc/{pid}/status") as f:
            total += sum(int(line.split()[1]) * 1024 for line in f if line.startswith("RssAnon:"))
        with open(f"/proc/{pid}/task/{pid}/children") as f:
            total += sum(anonymous_bytes(int(child)) for child in f.read().split())
    except OSError:
        pass
    return total


def peak_anonymous_bytes(proc, interval):
    """Samples the Popen `proc` (and its descendants) every `interval`
    seconds until it exits; returns the largest sample in bytes."""
    peak = 0
    while proc.poll() is None:
        peak = max(peak, anonymous_bytes(proc.pid))
        time.sleep(interval)
    return peak
