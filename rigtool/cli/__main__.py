"""`python -m rigtool.cli`: the same as the `rigtool` command."""

import sys

from rigtool.cli import main

sys.exit(main())
