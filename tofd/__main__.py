import sys

from tofd.cli import main

sys.exit(main())
