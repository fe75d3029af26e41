"""cloudcontrol: cloud control photogrammetry, from Python over the C ABI."""
from ._ffi import CloudControlError, last_error, version
from .control import DcpPackage, predict
from .geometry import Camera, Pose
from .matching import Match, fiducial_io, match_template
from .orient import NotOriented, PhotoOrientation, orient_photo

from . import lidar
from .pipeline import load_report, run

__all__ = [
    "CloudControlError", "Camera", "DcpPackage", "Match", "Pose", "fiducial_io", "last_error",
    "lidar", "load_report", "match_template", "NotOriented", "orient_photo", "PhotoOrientation", "predict", "run",
    "version",
]
