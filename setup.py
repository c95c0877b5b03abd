"""
Install the reducer_twin ament_python package.

``colcon build`` and ``pip install`` both read this file; ``setup.cfg`` sends
the console scripts to ``lib/reducer_twin`` under colcon, where ``ros2 run``
looks for them.
"""

from glob import glob

from setuptools import find_packages
from setuptools import setup

package_name = 'reducer_twin'

setup(
    name=package_name,
    version='0.1.0',
    # msg_adapters/ (the only code that knows both ROS message fields and core types) is
    # installed inside the package, as reducer_twin.msg_adapters, not as a top-level name.
    packages=find_packages(exclude=['test', 'test.*', 'bench', 'msg_adapters',
                                    'msg_adapters.*']) + ['reducer_twin.msg_adapters'],
    package_dir={'reducer_twin.msg_adapters': 'msg_adapters'},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', sorted(glob('config/*.yaml'))),
        ('share/' + package_name + '/config/foxglove', sorted(glob('config/foxglove/*.json'))),
        ('share/' + package_name + '/launch', sorted(glob('launch/*.launch.py'))),
    ],
    python_requires='>=3.10',
    # rclpy and the message packages come from the ROS installation (or from
    # requirements-ros.txt in a plain venv), never from here.
    install_requires=[
        'setuptools',
        'numpy',
        'scipy',
        'filterpy',
        'mcap',
        'lz4',
        "backports.zstd; python_version < '3.14'",
        'zstandard',
        'pyyaml',
        'rich',
        'matplotlib',
        # ROS 1 .bag files and stored message definitions (DynamicJointState) are read
        # with rosbags' rosbag1 reader and typesys.
        'rosbags',
    ],
    extras_require={
        # The fleet on Ray: analyze --engine ray (a local cluster on demand, or an existing one).
        'fleet': ['ray'],
        'test': [
            'pytest',
            'pytest-timeout',
            # The suite's modules spread over the cores (`make test`).
            'pytest-xdist',
            'hypothesis',
            'mcap-ros2-support',
            # What ament_flake8's configuration expects (its package.xml exec_depends).
            # Pinned: a new plugin release can add a rule and fail the lint tests.
            'flake8==7.5.0',
            'flake8-builtins==3.1.0',
            'flake8-comprehensions==3.17.0',
            'flake8-docstrings==1.7.0',
            'flake8-import-order==0.19.2',
            'flake8-quotes==3.4.0',
            'pydocstyle==6.3.0',
        ],
    },
    zip_safe=True,
    maintainer='reducer_twin maintainers',
    maintainer_email='maintainers@reducer-twin.invalid',
    description=(
        'Digital twin of precision cycloidal (RV) reducers: '
        'wear, transmission error and remaining life'
    ),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'reducer-twin = reducer_twin.cli:main',
            'joint_simulator = reducer_twin.nodes.joint_simulator:main',
            'encoder_ingest = reducer_twin.nodes.encoder_ingest:main',
            'te_monitor = reducer_twin.nodes.te_monitor:main',
            'wear_estimator = reducer_twin.nodes.wear_estimator:main',
            'life_publisher = reducer_twin.nodes.life_publisher:main',
            'twin_bringup = reducer_twin.nodes.twin_bringup:main',
        ],
    },
)
