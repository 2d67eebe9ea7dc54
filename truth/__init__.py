"""zentrack.truth: scenarios on disk and the truth process that publishes measurements."""
