"""One module per ``glove`` subcommand, each with ``add_parser(subparsers)``."""
