"""Command implementations behind the typer app in ``hoc_cli.cli``: one module per command.

They do the I/O (task files, URDFs, outputs, the terminal) around the pure maths modules.
"""
