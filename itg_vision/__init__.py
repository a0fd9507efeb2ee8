"""itg_vision: the Intelligent Trajectory Generator driven by stereo vision."""

__version__ = "0.1.0"
