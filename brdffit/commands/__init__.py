"""One module per ``brdffit`` subcommand, each with ``register(subparsers)``."""
