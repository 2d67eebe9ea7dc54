"""The single-target payload of a tracker's schedule: one target tracked by diffusion (the five seed systems'
scans, rounds of covariance intersection, relays and warm start), its estimation state and what it admits."""
