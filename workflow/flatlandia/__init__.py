"""Flatlandia: regenerate the object-map localization benchmark end to end."""

__version__ = "0.1.0"
