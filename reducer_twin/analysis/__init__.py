"""
Offline analysis of recorded bags: the core's stages over whole chunks, reports.

A process that analyses keeps the core's transmission-error tables on disk
(:mod:`reducer_twin.io.table_cache`), as the nodes and the command do.
"""

from reducer_twin.io import table_cache

table_cache.install()
