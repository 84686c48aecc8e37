"""The Python tests' daemon fixture: geodesicd serve on 127.0.0.1 port 0, the
ports it bound read back from --port-file, every wait bounded, and every
daemon started here stopped when the test process exits, however it exits.

Picking a "free" port by binding and closing a socket races with other tests;
the daemon's --port-file names the ports it really listens on.
"""
import atexit
import collections
import itertools
import json
import os
import re
import signal
import subprocess
import time
import urllib.request

import grpc

_started = []
_starts = itertools.count(1)


def watch(process):
    """Stops `process` at exit if it still runs (for daemons started elsewhere)."""
    _started.append(process)
    return process


def wait_for_ports(process, port_file, timeout=60, log=None):
    """The ports `process` wrote to `port_file`: RuntimeError, the process
    killed and the end of the file `log` quoted, if it exits first or has not
    written them within `timeout` s."""
    deadline = time.time() + timeout
    while not os.path.exists(port_file):
        why = None
        if process.poll() is not None:
            why = f"geodesicd exited with {process.returncode} before listening"
        elif time.time() > deadline:
            process.kill()
            process.wait(timeout=30)
            why = f"geodesicd wrote no {port_file} within {timeout} s"
        if why:
            if log:
                with open(log, errors="replace") as f:
                    why += ":\n" + f.read()[-4000:]
            raise RuntimeError(why)
        time.sleep(0.05)
    # The daemon writes the file by rename: once there, it is whole.
    with open(port_file) as f:
        return json.load(f)


def start_daemon(bin_dir, work, args, stderr=subprocess.DEVNULL, metrics=False, http=False,
                 timeout=60, tokens=None):
    """Returns (process, ports): ports["grpc"], and ports["metrics"] and
    ports["http"] when asked for (or listened on by `args`). With `tokens`, the
    daemon requires one of them on every call, each a client of its own (the
    way tests on one host tell clients apart)."""
    os.makedirs(work, exist_ok=True)
    if tokens:
        token_file = os.path.join(work, f"tokens.{next(_starts)}")
        with open(token_file, "w") as f:
            f.write("".join(f"{t}\n" for t in tokens))
        args = list(args) + ["--auth-token-file", token_file]
    # One file per start: a restarted daemon's file is never taken for the
    # last one's, and daemons sharing `work` each have their own.
    port_file = os.path.join(work, f"ports.{next(_starts)}.json")
    command = [f"{bin_dir}/geodesicd", "serve", "--listen", "127.0.0.1:0",
               "--port-file", port_file] + list(args)
    if metrics:
        command += ["--metrics-listen", "127.0.0.1:0"]
    if http:
        command += ["--http-listen", "127.0.0.1:0"]
    daemon = watch(subprocess.Popen(command, stderr=stderr))
    return daemon, wait_for_ports(daemon, port_file, timeout, getattr(stderr, "name", None))


def bearer(token):
    """The metadata that authenticates a call as `token`'s client."""
    return [("authorization", f"Bearer {token}")]


class _DefaultToken(grpc.UnaryUnaryClientInterceptor, grpc.UnaryStreamClientInterceptor,
                    grpc.StreamUnaryClientInterceptor, grpc.StreamStreamClientInterceptor):
    """Adds `token` to every call that names no token of its own."""

    def __init__(self, token):
        self.token = token

    def _with_token(self, details):
        metadata = list(details.metadata or [])
        if not any(k == "authorization" for k, _ in metadata):
            metadata += bearer(self.token)
        return details._replace(metadata=metadata) if hasattr(details, "_replace") else \
            _CallDetails(details.method, details.timeout, metadata, details.credentials,
                         getattr(details, "wait_for_ready", None),
                         getattr(details, "compression", None))

    def intercept_unary_unary(self, continuation, details, request):
        return continuation(self._with_token(details), request)

    def intercept_unary_stream(self, continuation, details, request):
        return continuation(self._with_token(details), request)

    def intercept_stream_unary(self, continuation, details, requests):
        return continuation(self._with_token(details), requests)

    def intercept_stream_stream(self, continuation, details, requests):
        return continuation(self._with_token(details), requests)


class _CallDetails(collections.namedtuple(
        "_CallDetails", ("method", "timeout", "metadata", "credentials", "wait_for_ready",
                         "compression")), grpc.ClientCallDetails):
    pass


def authed(channel, token):
    """`channel` with `token` sent on every call that names none of its own."""
    return grpc.intercept_channel(channel, _DefaultToken(token))


def stop(process, sig=signal.SIGTERM, timeout=30):
    """Sends `sig` and waits at most `timeout` s, then kills. Returns the exit
    code, or None if it had to be killed."""
    if process.poll() is not None:
        return process.returncode
    process.send_signal(sig)
    try:
        return process.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait(timeout=30)
        return None


def metrics(port):
    """The daemon's /metrics on `port` (its "metrics" port): {name: value} of every
    geodesicd_ series without labels."""
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=5) as r:
        text = r.read().decode()
    return {m.group(1): float(m.group(2))
            for m in re.finditer(r"^(geodesicd_\w+) (\S+)$", text, re.M)}


def rss_bytes(pid, field="VmRSS"):
    """A memory figure of /proc/PID/status (VmRSS, VmHWM, RssAnon, ...) in bytes."""
    with open(f"/proc/{pid}/status") as f:
        return int(re.search(rf"^{field}:\s+(\d+) kB", f.read(), re.M).group(1)) << 10


@atexit.register
def _stop_all():
    for process in _started:
        if process.poll() is None:
            process.kill()
            try:
                process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                pass
