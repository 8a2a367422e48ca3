"""The HIL bench: scenarios (TOML) of configuration, seed, fault plan, host actions and
assertions, run on the in-process emulator in fast mode; campaigns across processes or a
Dask cluster; Markdown, JSON and PNG reports.  ``hil-bench`` (tools/hil_bench/cli.py) is its
command line; docs/HIL_BENCH.md the schema.
"""
