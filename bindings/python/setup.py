"""Builds the wheel with the shared library inside it, so `pip install cloudcontrol-*.whl`
needs no build folder and no environment variable.

The library is found or built in this order: $CLOUDCONTROL_LIB (a built library to
bundle), else `cargo build --release --lib` in the repository this folder belongs to
(honouring $CARGO_TARGET_DIR). Python talks to it through ctypes only, so the wheel is
tagged py3-none-<platform>: one wheel for every CPython 3 on that platform.
"""
import os
import pathlib
import shutil
import subprocess
import sys

from setuptools import setup
from setuptools.command.build_py import build_py
from setuptools.dist import Distribution

try:
    from setuptools.command.bdist_wheel import bdist_wheel
except ImportError:  # setuptools < 70 ships it in the wheel package
    from wheel.bdist_wheel import bdist_wheel

HERE = pathlib.Path(__file__).resolve().parent
REPO = HERE.parents[1]
LIB_NAME = {"darwin": "libcloudcontrol.dylib", "win32": "cloudcontrol.dll"}.get(
    sys.platform, "libcloudcontrol.so")


def built_library() -> pathlib.Path:
    env = os.environ.get("CLOUDCONTROL_LIB")
    if env:
        lib = pathlib.Path(env)
        if not lib.is_file():
            raise SystemExit(f"CLOUDCONTROL_LIB={env}: no such file")
        return lib
    if not (REPO / "Cargo.toml").is_file():
        raise SystemExit(
            f"{REPO}: not the cloudcontrol repository; set CLOUDCONTROL_LIB to a built "
            f"{LIB_NAME} to bundle")
    subprocess.run(["cargo", "build", "--release", "--lib"], cwd=REPO, check=True)
    target = pathlib.Path(os.environ.get("CARGO_TARGET_DIR", REPO / "target"))
    if not target.is_absolute():
        target = REPO / target
    return target / "release" / LIB_NAME


class BuildPyWithLibrary(build_py):
    def run(self):
        super().run()
        if getattr(self, "editable_mode", False):
            return  # an editable install loads the repository's target/release build
        dest = pathlib.Path(self.build_lib) / "cloudcontrol" / LIB_NAME
        shutil.copy2(built_library(), dest)


class PlatformWheel(bdist_wheel):
    def get_tag(self):
        _, _, plat = super().get_tag()
        return "py3", "none", plat


class BinaryDistribution(Distribution):
    """The wheel holds a native library: it is platform-specific, never 'pure'."""

    def has_ext_modules(self):
        return True


setup(
    distclass=BinaryDistribution,
    cmdclass={"build_py": BuildPyWithLibrary, "bdist_wheel": PlatformWheel},
)
