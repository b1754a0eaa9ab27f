import sys

from coload.cli import main

sys.exit(main())
