"""The lowest layer of shared plumbing: argparse value types, the limits they share with the scenario files,
process helpers and free ports, atomic writes, progress and closing lines, and what commands and benches print
alike: aligned tables and JSON reports (:mod:`.report`), a run's summary table, failures and closing line
(:mod:`.run_summary`, with the stretches a tracker was cut off: :mod:`.outages`). No Zenoh, no scenarios."""
