"""skynav: deep-space optical navigation imagery (command line package)."""

try:
    from importlib.metadata import version as _version

    __version__ = _version("skynav")
except Exception:  # pragma: no cover - running from a source tree without install
    __version__ = "0.0.0+unknown"
