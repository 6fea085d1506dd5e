"""rigtool test suite."""
