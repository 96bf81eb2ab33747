"""The command line's commands, by concern: each module's ``register`` adds its subparsers, one function each."""
