import sys

from clradcom.cli import main

sys.exit(main())
