# The version of the bundled library (Cargo.toml's); tests/test_package.py checks both.
__version__ = "0.1.0"
