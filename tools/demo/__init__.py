"""``make demo`` (``python -m tools.demo [--realtime]``): the mug picked up by the hand on the
arm.  ``command`` is the command, ``script`` runs the steps (``realtime``: through a
``hil-emulator``'s ptys), ``plan`` says where things are, ``watch`` what it watches,
``report`` what it writes.
"""
