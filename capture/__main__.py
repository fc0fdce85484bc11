"""``python -m capture`` = ``vdc-capture``."""

from vdc.launch import capture

raise SystemExit(capture())
