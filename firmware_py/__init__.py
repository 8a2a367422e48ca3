"""Firmware of every microcontroller of the hand and arm, written against a small HAL."""

import protocol  # noqa: F401 - first: it decides compiled core or source
