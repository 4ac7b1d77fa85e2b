from sappc.cli import main
import sys

sys.exit(main())
