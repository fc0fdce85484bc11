"""What capture and analysis agree on, imported by both (neither imports the other for it):

* ``contract.recording``: the recording contract: application id, timelines, entity paths,
  property sections (DESIGN.md);
* ``contract.provenance``: the package versions and the machine every recording and table
  carries, so results from two machines can be compared.
"""
