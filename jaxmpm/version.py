"""The installed distribution's version (pyproject.toml)."""

from importlib.metadata import PackageNotFoundError, version


def installed_version() -> str:
    """The installed distribution's version; '0+unknown' when run from a checkout that is not
    installed."""
    try:
        return version("jaxmpm")
    except PackageNotFoundError:
        return "0+unknown"


__version__ = installed_version()
