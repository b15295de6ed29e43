import sys

from fbaconf.harness.cli import main

sys.exit(main())
