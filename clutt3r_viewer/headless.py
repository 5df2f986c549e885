"""What serving the viewer to a headless browser needs, in one place: a free local port and
Debian's chromium with the flags this project runs it with (export-html, the browser tests,
the viewer benchmarks and the screenshot scripts all use these)."""

from __future__ import annotations

import socket
from pathlib import Path

__all__ = ["CHROMIUM", "CHROMIUM_ARGS", "free_port"]

CHROMIUM = Path("/usr/bin/chromium")
"""Debian's chromium (``apt-get install chromium``; never ``playwright install``)."""

CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]
"""Launch flags: no sandbox (containers), software WebGL, and nothing that reaches the network."""


def free_port() -> int:
    """A TCP port on 127.0.0.1 that is free now (the OS picks it)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])
