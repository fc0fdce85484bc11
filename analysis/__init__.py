"""vdc's offline analysis: everything that consumes recordings and stimuli.

Sweeps (``analysis.sweep``), calibration output (``analysis.calibrate``) and Parquet tables
(``analysis.parquet_io``); the command line is ``vdc-analyse`` (``analysis.cli``).
"""
