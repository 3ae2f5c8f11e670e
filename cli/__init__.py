"""The ``colonlight`` command line: thin typer shells over the engine (installed as ``colonlight_cli``)."""
