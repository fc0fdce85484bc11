"""vdc's offline analysis: everything that consumes recordings and stimuli.

Tables, profiles, comparisons, batch analysis and the paper's experiments
(``analysis.experiments``), written as Parquet through ``vdc.parquet_io``; the command line is
``vdc-analyse`` (``analysis.cli``).
"""
