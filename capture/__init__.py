"""vdc's capture side: everything that produces a recording (simulated arena and robot, the
Colias serial link, the overhead tracker, and the Rerun recorder that alone knows the entity
paths and the blueprint)."""
