import sys

from jaxplan.cli.main import main

sys.exit(main())
