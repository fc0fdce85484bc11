"""The pre-registered power study (``vdc-analyse power-study``, docs/findings/power_plan.md).

* ``sizes``: how many arena conditions and footage clips the plan needs;
* ``pilot``: the footage pilot that sets the detectors' values;
* ``study``: the plan run from nothing; ``answer`` its answer from the tables it wrote
  (``units`` the units it ranks, scene by scene);
* ``resume``: what a resumed study may reuse (the code key);
* ``findings``: the answer published into the repository and the docs' result section.
"""
