"""``hil-bench replay``: drive an emulator with a recording's host bytes, at their recorded
times on the simulated clock, and say where its answers part from the recorded robot's.

``source`` reads a recording and works out the emulator it needs; ``exchanges`` pairs each
host request with its reply (by request, not by position) and names the reply's fields;
``drive`` feeds an emulator the host's bytes; ``compare`` measures each channel's error;
``session`` puts them together (:func:`~tools.hil_bench.replay.session.replay`, the function
a fitter calls many times); ``report`` and ``command`` are the report and the sub-command.
"""
