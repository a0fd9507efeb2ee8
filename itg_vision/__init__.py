"""itg_vision: the Intelligent Trajectory Generator driven by stereo vision."""

import sys as _sys

__version__ = "0.1.0"
__all__ = ["TrackingEnv"]

if _sys.argv[:1] == ["-m"]:  # a command starting (python -m itg_vision....), not a library use
    import os as _os
    import signal as _signal

    def _interrupted_at_start(signum, frame):
        """Ctrl-C while the command's modules load (up to ~1 s): the word a command prints,
        status 130, not a traceback from inside an import. The process ends here: an exception
        raised in the handler could be caught by the code it interrupts (numpy's C-extension
        import turned one into an ImportError traceback, status 1), and nothing is written yet
        to be lost. The command's body (errors.run_main) puts Python's own handler back."""
        _sys.stderr.write("\ninterrupted\n")
        _sys.stderr.flush()
        _os._exit(130)

    if _signal.getsignal(_signal.SIGINT) is _signal.default_int_handler:
        _signal.signal(_signal.SIGINT, _interrupted_at_start)


def __getattr__(name: str):
    # imported on first use: gymnasium and pybullet load only for who needs them
    if name == "TrackingEnv":
        from .env import TrackingEnv

        return TrackingEnv
    raise AttributeError(f"module 'itg_vision' has no attribute {name!r}")
