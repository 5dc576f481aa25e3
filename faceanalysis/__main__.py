import sys

from faceanalysis.cli.main import main

sys.exit(main())
