"""``python -m capture`` = ``vdc-capture``."""

from contract.launch import capture

raise SystemExit(capture())
