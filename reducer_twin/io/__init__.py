# noqa: A005 - reducer_twin.io is a subpackage, always imported by its full name
"""
Every byte the twin reads from or writes to a disk.

rosbag2 bags (directories with ``metadata.yaml``, split files, MCAP and sqlite3 ``.db3``
storage) and ROS 1 ``.bag`` files; derived bags framed with the mcap library; the fast
array writer and reader that keep the JointState hot path in numpy; estimator state
files; the transmission-error cache. The core below it takes and returns arrays and
dicts and never opens a file.
"""
