"""The ``armvision`` command line (see :mod:`armvision.cli.main`)."""

from armvision.cli.main import main

__all__ = ["main"]
