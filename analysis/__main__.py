"""``python -m analysis`` = ``vdc-analyse``."""

from contract.launch import analyse

raise SystemExit(analyse())
