"""The two consoles every command prints on: results to stdout, warnings and errors to stderr."""

from __future__ import annotations

import sys

from rich.console import Console

# Pipes and logs get wide tables instead of rich's 80-column default.
# markup off: run names, reasons and file contents are printed literally, never as Rich markup
out = Console(highlight=False, markup=False, soft_wrap=True,
              width=None if sys.stdout.isatty() else 160)
err = Console(stderr=True, highlight=False, markup=False, soft_wrap=True,
              width=None if sys.stderr.isatty() else 160)
