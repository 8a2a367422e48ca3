"""Experiments repeated on the emulator: ``dissertation`` (``hil-bench experiments``) repeats
the dissertation's chapter 5 and 6 measurements and compares them with the published figures.
"""
