import sys

from bayescalib.cli import main

sys.exit(main())
