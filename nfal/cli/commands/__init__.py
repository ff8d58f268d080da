"""Command groups of the ``nfal`` command line; each module has ``register(subparsers)``."""
