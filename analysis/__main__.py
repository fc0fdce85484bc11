"""``python -m analysis`` = ``vdc-analyse``."""

from vdc.launch import analyse

raise SystemExit(analyse())
