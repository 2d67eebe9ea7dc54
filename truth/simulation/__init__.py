"""zentrack.truth.simulation: what the truth process simulates, and what studies and the configuration simulate
with it (layers: docs/architecture.md, "Packages and layers"): scenario specs (:mod:`.scenario_spec`) and runs'
data (:mod:`.scenario`), drawing runs (:mod:`.simulate`), clutter (:mod:`.clutter`), satellite orbits
(:mod:`.orbit`), paper 4's extended object (:mod:`.eot_scenario`), the patrol (:mod:`.patrol`), many targets
(:mod:`.multitarget`, their sensing :mod:`.mt_sensors`) and recorded trajectories (:mod:`.recorded`).

Below the configuration layer and above ``zentrack.fusion``: it imports numpy and ``zentrack.fusion`` only (SciPy
in the few functions that need it), and no tracker imports it (``tests/test_layers.py`` checks that nothing
``zentrack.node`` imports reaches it). Importing this package imports none of its modules.
"""
