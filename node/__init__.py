"""zentrack.node: the tracker process (``zentrack node``) and its I/O-free estimation state."""
