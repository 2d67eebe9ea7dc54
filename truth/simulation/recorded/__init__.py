"""Recorded trajectories (AIS vessels, ADS-B aircraft) as the truth of a many-target run: the data sources, their
cleaning and interpolation, and the targets at every scan."""
