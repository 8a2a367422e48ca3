"""Runnable examples of docs/HOST.md; tests/host/test_host_examples.py runs each on ``emu://``."""
