"""The experiments that re-create the paper; the only part of ``analysis`` that imports
``capture`` (to render stimuli and record the runs it then analyses).

* ``sweep``: AVDM response over the SF–TF plane (Fig. 3);
* ``calibrate``: the least-squares fit of the decoding constants (a, b);
* ``approach``: the open-loop approach to a wall (Fig. 4);
* ``captures``: simulated runs recorded in parallel, reused when already there;
* ``collision_study``: the three-phase collision protocol plus the adaptive detector (Fig. 8);
* ``reproduce``: all of the above and the claim-by-claim report.
"""
