"""The command-line programs (one module per installed command, see ``[project.scripts]``)
and what they share: ``common`` (``--port``, ``--json``, ``--timeout``, one error-to-exit
mapping), ``numeric`` (every numeric option checked one way), ``output`` (``guard_output``),
``values`` (field values on the command line), ``view`` (``--view``, ``watch``) and
``mcap_capture`` (``handbus decode FILE.mcap``).
"""
