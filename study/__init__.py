"""zentrack.study: the tools of Monte Carlo studies (layers: docs/architecture.md, "Packages and layers"): the
batched network simulator (:mod:`.simulator`), the posterior Cramér–Rao bound (:mod:`.pcrlb`), accuracy metrics
(:mod:`.metrics`; the multi-target metrics, GOSPA, OSPA and identity switches, live in
:mod:`zentrack.fusion.multitarget.metrics`, below every process) and paper 4's batched network algorithms
(:mod:`.eot_network`).

It imports ``zentrack.fusion`` and ``zentrack.truth.simulation``; no process (tracker, truth, viewer) imports it.
Importing this package imports none of its modules.
"""
