"""zentrack.viewer: the Rerun viewer process (``zentrack viewer``) and its geometry helpers."""
