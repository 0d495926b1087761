import sys

from tipbot_fw.cli import main

sys.exit(main())
