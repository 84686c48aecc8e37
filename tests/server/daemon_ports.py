"""Starts geodesicd on 127.0.0.1 port 0 and reads back the ports it bound.

Picking a "free" port by binding and closing a socket races with other tests;
the daemon's --port-file names the ports it really listens on.
"""
import json
import os
import subprocess
import time


def start_daemon(bin_dir, work, args, stderr=subprocess.DEVNULL, metrics=False):
    """Returns (process, ports): ports["grpc"], and ports["metrics"] when asked for."""
    port_file = os.path.join(work, "ports.json")
    if os.path.exists(port_file):
        os.remove(port_file)
    command = [f"{bin_dir}/geodesicd", "serve", "--listen", "127.0.0.1:0",
               "--port-file", port_file] + list(args)
    if metrics:
        command += ["--metrics-listen", "127.0.0.1:0"]
    daemon = subprocess.Popen(command, stderr=stderr)
    deadline = time.time() + 60
    while not os.path.exists(port_file):
        if daemon.poll() is not None:
            raise RuntimeError(f"geodesicd exited with {daemon.returncode} before listening")
        if time.time() > deadline:
            daemon.kill()
            raise RuntimeError(f"geodesicd wrote no {port_file} within 60 s")
        time.sleep(0.05)
    with open(port_file) as f:
        return daemon, json.load(f)
