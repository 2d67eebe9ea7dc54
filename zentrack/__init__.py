"""zentrack: distributed multi-sensor target tracking (twice-extended-state Kalman filters, CI diffusion)."""
__version__ = "0.1.0"
