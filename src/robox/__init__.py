"""Toolkit and firmware model for the CEL Robox 3D printer."""

__version__ = "0.1.0"
