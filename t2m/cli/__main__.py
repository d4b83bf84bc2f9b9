import sys

from t2m.cli.main import main

sys.exit(main())
