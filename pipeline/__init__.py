"""baarda's engine: data model, stage protocol, plugin manager, runner, command line."""

__version__ = "0.1.0"
