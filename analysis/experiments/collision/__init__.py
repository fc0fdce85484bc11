"""Where collision detectors fail, against complexity: the campaigns that record the runs and
clips (the paper's own collision study is ``analysis.experiments.paper.collision_study``).

* ``boundary_campaign``: the arena campaign of ``vdc-analyse boundary`` (the grid and the
  profiling runs; its settings and statistics are in ``analysis.boundary``), ``adaptive`` its
  adaptive design (its loop in ``design``, ``--per-scene``'s in ``per_scene``);
* ``adaptation``: a learnt policy tested in closed loop where it was not learnt;
* ``looming_footage``: a labelled collection of looming clips over real photographs;
* ``predictor_runs``: every complexity measure of a grid's profiling runs.
"""
