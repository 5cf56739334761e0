"""Sub-commands of the `intspace` command line; each module has `register(subparsers)`."""
