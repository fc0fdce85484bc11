"""``python -m capture`` = ``vdc-capture``."""

from capture.cli import main

raise SystemExit(main())
