"""
The twin's ROS 2 nodes, one per module, each with ``main``.

A process that runs nodes keeps the core's transmission-error tables on disk
(:mod:`reducer_twin.io.table_cache`), so a restarted node does not rebuild them.
"""

from reducer_twin.io import table_cache

table_cache.install()
