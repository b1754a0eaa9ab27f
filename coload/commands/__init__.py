"""The handlers of the ``coload`` subcommands, one module per group (the parser is coload/cli.py)."""
