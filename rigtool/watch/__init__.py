"""`rigtool watch`: a local web page that follows a running or finished run, read-only
(docs/watch.md). data.py turns one snapshot of the store into the page's JSON; server.py
serves it with the bundled page (static/: index.html, app.js, uPlot and its licence)."""

from __future__ import annotations

from rigtool.watch.data import Watcher
from rigtool.watch.server import DEFAULT_PORT, WatchServer

__all__ = ["DEFAULT_PORT", "WatchServer", "Watcher"]
