"""Subcommands of the ``compass`` command line, one module each (see :mod:`compass.cli`)."""
