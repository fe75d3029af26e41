"""cloudcontrol: cloud control photogrammetry, from Python over the C ABI."""
from ._ffi import (CloudControlError, InputNotFoundError, InputOutputError, InvalidInputError,
                   last_error, version)
from ._version import __version__
from .control import DcpPackage, predict
from .dense import match_pair
from .geometry import Camera, Pose
from .matching import Match, fiducial_io, match_template
from .orient import NotOriented, PhotoOrientation, orient_photo

from . import lidar
from .pipeline import PartialRunError, load_report, run

__all__ = [
    "CloudControlError", "InputNotFoundError", "InputOutputError", "InvalidInputError", "Camera", "DcpPackage", "Match", "Pose", "fiducial_io", "last_error",
    "lidar", "load_report", "match_pair", "match_template", "NotOriented", "orient_photo", "PartialRunError", "PhotoOrientation", "predict", "run",
    "version",
]
