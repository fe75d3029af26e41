"""cloudcontrol: cloud control photogrammetry, from Python over the C ABI."""
from ._ffi import CloudControlError, last_error, version
from .geometry import Camera, Pose
from . import lidar

__all__ = ["CloudControlError", "Camera", "Pose", "last_error", "lidar", "version"]
