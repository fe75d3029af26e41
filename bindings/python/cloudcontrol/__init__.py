"""cloudcontrol: cloud control photogrammetry, from Python over the C ABI."""
from ._ffi import CloudControlError, last_error, version
from .geometry import Camera, Pose

__all__ = ["CloudControlError", "Camera", "Pose", "last_error", "version"]
