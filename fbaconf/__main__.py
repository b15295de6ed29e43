import sys

from fbaconf.cli import main

sys.exit(main())
