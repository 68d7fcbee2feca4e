import sys

from prismstereo.apps.cli import main

sys.exit(main())
