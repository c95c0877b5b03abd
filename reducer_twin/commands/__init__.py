"""Subcommands of ``reducer-twin``, one module each."""
