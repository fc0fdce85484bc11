"""Put on PYTHONPATH by ``tests.figures.figure_env`` only: every process of a command a test
runs records the figures it saves (see tests/figures.py, loaded by its path: the command's
folder need not be the repository)."""

import os

if os.environ.get("VDC_TEST_FIGURES"):
    import importlib.util
    from pathlib import Path

    _spec = importlib.util.spec_from_file_location(
        "_vdc_test_figures", Path(__file__).resolve().parents[1] / "figures.py"
    )
    _figures = importlib.util.module_from_spec(_spec)
    _spec.loader.exec_module(_figures)
    _figures.install_from_env()
