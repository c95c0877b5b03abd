"""reducer_twin: a ROS 2 digital twin of precision cycloidal (RV) reducers."""

import os as _os

__version__ = '0.1.0'

# The message adapters live in the checkout's top-level msg_adapters/ directory, which
# setup.py installs as reducer_twin.msg_adapters (package_dir). Run from a checkout (or
# an editable install), the same name reaches that directory: the checkout is searched
# for this package's submodules after the package's own directory.
_CHECKOUT = _os.path.dirname(_os.path.dirname(_os.path.abspath(__file__)))
if not _os.path.isdir(_os.path.join(_os.path.dirname(__file__), 'msg_adapters')) and \
        _os.path.isfile(_os.path.join(_CHECKOUT, 'msg_adapters', '__init__.py')):
    __path__.append(_CHECKOUT)
