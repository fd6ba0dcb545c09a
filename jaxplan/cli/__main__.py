"""``python -m jaxplan.cli``: the command line as a process (``jaxplan.cli.entry``)."""
from jaxplan.cli.main import entry

entry()
