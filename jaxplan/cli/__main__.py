"""``python -m jaxplan.cli``: the command line as a process (``jaxplan.cli.entry``)."""
from jaxplan.cli import entry

entry()
