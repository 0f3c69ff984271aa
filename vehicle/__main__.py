import sys

from vehicle.cli import main

sys.exit(main())
