import sys

from prismstereo.cli import main

sys.exit(main())
