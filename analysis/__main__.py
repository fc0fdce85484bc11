"""``python -m analysis`` = ``vdc-analyse``."""

from analysis.cli import main

raise SystemExit(main())
