"""The paper's figures and claims, re-created.

* ``sweep``: AVDM response over the SF–TF plane (Fig. 3);
* ``calibrate``: the least-squares fit of the decoding constants (a, b);
* ``approach``: the open-loop approach to a wall (Fig. 4);
* ``collision_study``: the three-phase collision protocol plus the adaptive detector (Fig. 8);
* ``reproduce``: all of the above and the claim-by-claim report (``plan``: its durations and
  seeds; ``claims``: the claims and their numbers; ``report`` and ``figures``: the report).
"""
