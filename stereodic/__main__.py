import sys

from stereodic.cli import main

sys.exit(main())
