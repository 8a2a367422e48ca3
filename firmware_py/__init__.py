"""Firmware of every microcontroller of the hand and arm, written against a small HAL."""
