"""zentrack.truth.simulation: what the truth process simulates, and what studies and the configuration simulate
with it (DESIGN.md "Layout"): scenario specs and runs' data (:mod:`.scenario`), drawing runs (:mod:`.simulate`),
clutter (:mod:`.clutter`), satellite orbits (:mod:`.orbit`) and paper 4's extended object (:mod:`.eot_scenario`).

Below the configuration layer and above ``zentrack.fusion``: it imports numpy and ``zentrack.fusion`` only, and
no tracker imports it. Importing this package imports none of its modules.
"""
