"""Subcommands of `tofd`: each module has a docstring (its help), add_arguments(parser) and main(args) -> int.

Modules import heavy dependencies inside main(), so `tofd --help` stays fast.
"""
