"""`python -m rigtool`: the same as the `rigtool` command."""

from rigtool.launch import run

run()
