"""reducer_twin: a ROS 2 digital twin of precision cycloidal (RV) reducers."""

__version__ = '0.1.0'
