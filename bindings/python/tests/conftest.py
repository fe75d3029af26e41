import fcntl
import os
import pathlib
import shutil
import subprocess
import sys

import pytest

# Tests run against the package in this repository even without `pip install -e`.
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

ROOT = pathlib.Path(__file__).resolve().parents[3]
CLI = pathlib.Path(os.environ.get("CLOUDCONTROL_CLI", ROOT / "target" / "release" / "cloudcontrol"))


def block_copy(preset: str, seed: int, pos: str, dest: pathlib.Path) -> pathlib.Path:
    """A private copy at ``dest`` of the synthetic block the Rust tests share
    (``target/tmp/blocks/<preset>-<seed>-<pos>``, tests/common/mod.rs ``shared_block``):
    generated once per build of the CLI, into a private folder renamed into place, with a
    stamp of the CLI binary (size and modification time in ns) beside it. The check and the
    generation hold an exclusive flock of ``<key>.lock``, as the Rust tests' do: test.sh
    runs both suites side by side."""
    root = ROOT / "target" / "tmp" / "blocks"
    root.mkdir(parents=True, exist_ok=True)
    key = f"{preset}-{seed}-{pos}"
    shared, stamp_file = root / key, root / f"{key}.stamp"
    st = CLI.stat()
    stamp = f"{st.st_size}-{st.st_mtime_ns}"
    with open(root / f"{key}.lock", "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        fresh = (shared / "manifest.json").is_file() and stamp_file.is_file() \
            and stamp_file.read_text().strip() == stamp
        if not fresh:
            stamp_file.unlink(missing_ok=True)
            tmp = root / f".{key}.{os.getpid()}"
            shutil.rmtree(tmp, ignore_errors=True)
            subprocess.run([str(CLI), "synth", "-q", "--preset", preset, "--pos", pos,
                            "--seed", str(seed), "--out", str(tmp)], check=True)
            shutil.rmtree(shared, ignore_errors=True)
            tmp.rename(shared)
            stamp_file.write_text(stamp)
    shutil.rmtree(dest, ignore_errors=True)
    shutil.copytree(shared, dest)
    return dest


@pytest.fixture(scope="session")
def shared_block():
    """:func:`block_copy`, for module fixtures."""
    return block_copy
