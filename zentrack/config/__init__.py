"""Configuration: run setup from flags, TOML scenarios and recorded ``.npz`` scenarios, and their bounds."""
