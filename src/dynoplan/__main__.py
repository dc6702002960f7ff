"""``python -m dynoplan ...``: the ``dynoplan`` command (:func:`dynoplan.cli.main.main`)."""

from dynoplan.cli.main import main

if __name__ == "__main__":
    main()
