"""The package's version, written once: in ``pyproject.toml``, read here from the installed
metadata (``vdc.__version__`` and ``avdm.__version__`` are this)."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("visual-dynamic-complexity")
except PackageNotFoundError:  # a source tree never installed: say so rather than guess
    __version__ = "0+unknown"
