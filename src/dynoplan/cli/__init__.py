"""The ``dynoplan`` command line."""
