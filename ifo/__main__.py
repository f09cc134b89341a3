import sys

from ifo.cli import main

sys.exit(main())
