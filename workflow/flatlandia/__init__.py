"""Flatlandia: regenerate the object-map localization benchmark end to end."""

from flatlandia.release import package_version

#: pyproject.toml's version (flatlandia.release)
__version__ = package_version()
