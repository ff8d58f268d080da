import sys

from nfal.cli import main

sys.exit(main())
