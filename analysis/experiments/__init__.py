"""The experiments: the only part of ``analysis`` that imports ``capture`` (to render stimuli
and record the runs it then analyses), as packages by what they re-create.

* ``paper``: the paper's figures and claims (the SF–TF sweep, the decoding calibration, the
  open-loop approach, the three-phase collision study) and ``reproduce``, which runs them all
  and reports claim by claim;
* ``collision``: where collision detectors fail: the arena campaign of ``vdc-analyse boundary``
  (its grid and adaptive designs), a learnt policy tested in closed loop (``adaptation``), the
  labelled looming footage, and every complexity measure of a grid's runs;
* ``power``: the pre-registered power study (``vdc-analyse power-study``): the plan's sizes,
  its pilot, its runs, its answer, what a resumed study may reuse and the published findings;
* ``captures`` (shared by all three): simulated runs recorded in parallel, reused when already
  there.
"""
