"""`python -m rigtool`: the same as the `rigtool` command."""

import sys

from rigtool.cli import main

sys.exit(main())
