"""itg_vision: the Intelligent Trajectory Generator driven by stereo vision."""

__version__ = "0.1.0"
__all__ = ["TrackingEnv"]


def __getattr__(name: str):
    # imported on first use: gymnasium and pybullet load only for who needs them
    if name == "TrackingEnv":
        from .env import TrackingEnv

        return TrackingEnv
    raise AttributeError(f"module 'itg_vision' has no attribute {name!r}")
