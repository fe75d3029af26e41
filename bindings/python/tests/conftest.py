import pathlib
import sys

# Tests run against the package in this repository even without `pip install -e`.
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))
