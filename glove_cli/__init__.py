"""The ``glove`` command line: one subcommand per user-facing job."""
