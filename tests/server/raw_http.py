"""Reading one HTTP/1.1 response off a raw socket, for the tests that speak
HTTP by hand (hostile clients, connection caps, 401s that must close)."""

import socket
import time


def read_response(sock, timeout=5.0):
    """(status, headers dict lower-cased, body) of one response, or None if the
    connection closed (or reset) before a status line."""
    deadline = time.time() + timeout
    data = b""
    while b"\r\n\r\n" not in data:
        left = deadline - time.time()
        if left <= 0:
            raise TimeoutError(f"no complete response headers within {timeout} s: {data[:200]!r}")
        sock.settimeout(left)
        try:
            chunk = sock.recv(65536)
        except (ConnectionResetError, BrokenPipeError):
            chunk = b""
        if not chunk:
            return None if not data else (0, {}, data)
        data += chunk
    head, _, body = data.partition(b"\r\n\r\n")
    lines = head.decode("latin-1").split("\r\n")
    status = int(lines[0].split()[1])
    headers = {}
    for line in lines[1:]:
        name, _, value = line.partition(":")
        headers[name.strip().lower()] = value.strip()
    length = int(headers.get("content-length", "0"))
    while len(body) < length and time.time() < deadline:
        sock.settimeout(max(0.01, deadline - time.time()))
        try:
            chunk = sock.recv(65536)
        except (ConnectionResetError, BrokenPipeError, socket.timeout):
            break
        if not chunk:
            break
        body += chunk
    return status, headers, body
