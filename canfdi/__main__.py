import sys

from canfdi.cli import main

sys.exit(main())
