"""cloudcontrol: cloud control photogrammetry, from Python over the C ABI."""
from ._ffi import CloudControlError, last_error, version
from .control import DcpPackage, predict
from .geometry import Camera, Pose

__all__ = ["CloudControlError", "Camera", "DcpPackage", "Pose", "last_error", "predict", "version"]
