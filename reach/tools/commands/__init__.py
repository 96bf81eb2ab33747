"""The command line's commands, by concern: each module's ``COMMANDS`` register their subparsers, one function each."""
