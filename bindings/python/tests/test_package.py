"""The package as a GIS script author gets it: a wheel that carries the library, installed
with pip into a fresh virtual environment (no CLOUDCONTROL_LIB, no repository on the path),
its version, its typing marker, its exceptions, and the example and Dask snippet of the
README run as scripts there."""
import os
import pathlib
import re
import subprocess
import sys
import venv

import pytest

import cloudcontrol

ROOT = pathlib.Path(__file__).resolve().parents[3]
LIB = ROOT / "target" / "release" / "libcloudcontrol.so"


def cargo_version() -> str:
    text = (ROOT / "Cargo.toml").read_text()
    return re.search(r'^version = "([^"]+)"', text, re.M).group(1)


def clean_env() -> dict:
    """The environment of a user who only pip-installed the wheel."""
    env = {k: v for k, v in os.environ.items()
           if k not in ("CLOUDCONTROL_LIB", "PYTHONPATH", "VIRTUAL_ENV")}
    return env


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """A fresh venv with the built wheel and its `examples` and `dask` extras."""
    tmp = tmp_path_factory.mktemp("package")
    dist = tmp / "dist"
    # The library of this build is bundled (CLOUDCONTROL_LIB), so the wheel build does not
    # run cargo again; without it setup.py runs `cargo build --release --lib` itself.
    subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(dist),
                    str(ROOT / "bindings" / "python")],
                   check=True, env={**os.environ, "CLOUDCONTROL_LIB": str(LIB)})
    wheels = list(dist.glob("cloudcontrol-*.whl"))
    assert len(wheels) == 1, wheels
    env_dir = tmp / "venv"
    venv.EnvBuilder(with_pip=True).create(env_dir)
    py = env_dir / "bin" / "python"
    subprocess.run([str(py), "-m", "pip", "install", "-q", f"{wheels[0]}[examples,dask]"],
                   check=True, env=clean_env(), cwd=tmp)
    return wheels[0], py, tmp


def test_the_wheel_is_tagged_for_its_platform_and_carries_the_library(installed):
    wheel, _, _ = installed
    # ctypes only: one wheel for every CPython 3, but bound to the platform of the library.
    assert re.fullmatch(rf"cloudcontrol-{re.escape(cargo_version())}-py3-none-linux_\w+\.whl",
                        wheel.name), wheel.name
    import zipfile
    names = zipfile.ZipFile(wheel).namelist()
    assert "cloudcontrol/libcloudcontrol.so" in names
    assert "cloudcontrol/py.typed" in names


def test_import_needs_no_environment_variable_and_loads_the_bundled_library(installed):
    _, py, tmp = installed
    out = subprocess.run(
        [str(py), "-c", "import cloudcontrol, cloudcontrol._ffi as f; "
                        "print(cloudcontrol.__version__); print(cloudcontrol.version()); print(f.lib._name)"],
        check=True, capture_output=True, text=True, env=clean_env(), cwd=tmp).stdout.split("\n")
    assert out[0] == cargo_version()
    assert out[1].startswith(cargo_version()), out
    assert pathlib.Path(out[2]).parent.parent.name == "site-packages", out[2]


def test_errors_are_pythons_own_exceptions(tmp_path):
    missing = tmp_path / "missing.json"
    with pytest.raises(FileNotFoundError, match="missing.json") as e:
        cloudcontrol.DcpPackage(missing)
    assert isinstance(e.value, cloudcontrol.CloudControlError)
    with pytest.raises(ValueError, match="outside"):
        cloudcontrol.Camera(-1, 1000, 1000.0, 1000.0, 500.0, 500.0)
    with pytest.raises(ValueError, match="outside"):
        cloudcontrol.Camera(1 << 32, 1000, 1000.0, 1000.0, 500.0, 500.0)
    assert cloudcontrol.__version__ == cargo_version()


def test_example_and_dask_snippet_run_as_scripts(installed, shared_block, tmp_path):
    _, py, _ = installed
    block = shared_block("small", 7, "rough", tmp_path / "block")
    # What is tested is that the example and the snippet run as scripts: the orientation
    # suffices, without the epochs' surfaces and changes (half of the run; test_pipeline
    # and test_distributed make them).
    with open(block / "project.toml", "a") as f:
        f.write("\n[outputs]\ndsm = false\nchange = false\n")
    png = tmp_path / "checkpoints.png"
    subprocess.run([str(py), str(ROOT / "bindings" / "python" / "examples" / "run_and_plot.py"),
                    str(block / "project.toml"), str(png)],
                   check=True, env=clean_env(), cwd=tmp_path, timeout=900)
    assert png.stat().st_size > 10_000
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    # The README's Dask snippet, as written, saved as a script next to the project. The
    # run above left its outputs, so the distributed run finds every stage done: what is
    # tested here is that the snippet starts its cluster and returns as a script.
    readme = (ROOT / "README.md").read_text()
    section = readme[readme.index("## Beyond one machine: Dask"):]
    snippet = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    script = block / "dask_snippet.py"
    script.write_text(snippet)
    out = subprocess.run([str(py), str(script)], capture_output=True, text=True,
                         env=clean_env(), cwd=block, timeout=900)
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.strip().startswith("["), out.stdout[-2000:]
